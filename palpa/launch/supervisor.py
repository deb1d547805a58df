"""Running a :class:`~palpa.launch.plan.LaunchPlan`: the bus first (in this process), then the recorder (if the
file records) until its heartbeat is heard, then the nodes; supervise them; stop them in stages.

Everything happens on the calling thread (which must be the main thread: signals, and PR_SET_PDEATHSIG fires
when the thread that forked a child exits): one loop waits on the children's output pipes and a signal wake-up
fd, reaps exits, respawns with backoff, escalates stops, and spins an in-process node for heartbeats/progress.

Stopping (Ctrl-C, SIGTERM, SIGHUP, or a required node's exit): every node gets SIGINT (to its process group),
SIGTERM after its ``sigterm_timeout``, SIGKILL after a further ``sigkill_timeout``; the recorder is stopped the
same way once the others are gone, then the bus. A second Ctrl-C moves every stopping node on to the next signal
at once. The launcher names each node that needed SIGTERM or SIGKILL.

Exit code: the required node's exit code when one ended the launch (128+N if killed by signal N); otherwise 0,
unless a node failed (exited non-zero, or gave up respawning, without being asked to stop): then 1. A simulated
graph whose time stood still for its clock's ``frozen_after_s`` (wall seconds) is ended with 1, and so is one
stopped by Ctrl-C while its time stood still (palpa.launch.clockwatch).

This module decides (when to spawn, respawn, stop, escalate, end the launch); palpa.launch.nodeproc keeps each
node's record, reads its output and carries out its staged stop, palpa.launch.spawn starts a node's process (its
environment, its start gate), palpa.launch.exits answers a node's end (its outcome, a respawn, a stop of the
launch), palpa.launch.respawn is the respawn policy, palpa.launch.observer the launcher's own node on the bus
(heartbeats, progress, the clock's ticks), palpa.launch.signals brings the signals into the loop,
palpa.launch.summary words the outcomes and makes the exit code.
"""

from __future__ import annotations

import contextlib
import secrets
import selectors
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from palpa.atomic import write_beside
from palpa.current import announce, withdraw
from palpa.errors import LaunchError
from palpa.launch.clockwatch import ClockWatch
from palpa.launch.exits import ended_by_itself, ended_when_asked
from palpa.launch.nodeproc import NodeProc
from palpa.launch.observer import Observer
from palpa.launch.output import Screen
from palpa.launch.plan import RECORDER_NAME, LaunchPlan, NodeSpec
from palpa.launch.prepare import Prepare
from palpa.launch.process import Child
from palpa.launch.reaper import Reaper
from palpa.launch.signals import SignalInbox
from palpa.launch.spawn import child_env, start_child
from palpa.launch.summary import exit_text, report_hidden, summarize
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.startgate import release

__all__ = ["Supervisor", "exit_text"]

_STEP_S = 0.05
_CALLED_OFF_S = 10.0
"""How long a launch that gave up before its nodes waits for the entries it had started at a start gate to leave
by themselves (they only import until then) before it kills them."""
_EXITED = "exited"
"""The selector's mark on a child's pidfd (palpa.launch.process.Child.exit_fd)."""


class Supervisor:
    """Runs one launch plan to the end. ``run()`` returns the launch's exit code.

    ``bus_address`` overrides the plan's bus (any form ``palpa --bus`` accepts, or ``tcp://HOST`` for
    OS-chosen ports); ``progress`` False hides the progress view (default: a bar on a terminal, plain lines
    every 5 % elsewhere);
    ``reaper`` False leaves only PR_SET_PDEATHSIG to clean up after a killed launcher (tests use it to prove
    that mechanism alone); ``announce`` lists this launch among the running ones the CLI tools find (palpa.current)."""

    def __init__(self, plan: LaunchPlan, *, bus_address: str | None = None, out: TextIO | None = None,
                 err: TextIO | None = None, progress: bool | None = None, reaper: bool = True,
                 announce: bool = False) -> None:
        self.plan = plan
        self.out = out or sys.stdout
        self.err = err or sys.stderr
        self._bus_override = bus_address
        self._progress_opt = progress
        self._procs: list[NodeProc] = []
        self._recorder: NodeProc | None = None
        self._sel = selectors.DefaultSelector()
        self._inbox = SignalInbox()
        self._stopping = False
        self._all_started = False
        self._reason = ""
        self._code: int | None = None
        self._screen = Screen(self.out, self.err)
        self._observer = Observer(self._screen, self.out)
        self.address: BusAddress | None = None
        self._use_reaper = reaper
        self._announce = announce
        self._entry: Path | None = None
        """This launch's entry among the running launches (palpa.current), while it runs."""
        self._reaper: Reaper | None = None
        self._clock_watch = ClockWatch.for_plan(plan)
        self._clock_master = secrets.token_bytes(32)
        """This run's master key for signed clock acks (palpa.timing.acksign): each child gets its own node's key,
        the clock entry the master."""
        self._gates: list[int] = []
        """Write ends of the start gates of the entries started before the checks and the prepare step."""

    # -- public ----------------------------------------------------------------------------------------
    def request_stop(self) -> None:
        """Ask the launch to stop as if Ctrl-C was pressed (safe from other threads and signal handlers)."""
        self._inbox.push(signal.SIGINT)

    def run(self) -> int:
        """Start everything, supervise until the launch ends, stop everything; returns the exit code."""
        plan = self.plan
        rec_spec = plan.recorder()
        if rec_spec is not None and not plan.recorder_available:
            raise LaunchError(f"{plan.files[0] if plan.files else plan.file}: the file asks to record, but "
                              "palpa.record.recorder:Recorder is not importable here")
        # an entry that can wait at a start gate (the composed simulation) starts first and imports its code
        # while the node checks, the bus and the prepare commands run; it builds nothing before the go
        gated = any(s.gate for s in plan.nodes) and bool(plan.prepare or plan.pending_checks)
        if not gated:
            self._run_checks()  # before anything is written: a file that fails them leaves nothing
        plan.run_dir.mkdir(parents=True, exist_ok=True)
        self._screen.open_launch_log(plan.run_dir / "launch.log")
        (plan.run_dir / "launch.resolved.yaml").write_text(plan.to_yaml(), encoding="utf-8")
        old = self._inbox.install(self._sel)
        bus: Bus | None = None
        try:
            for i, spec in enumerate(plan.nodes):
                self._procs.append(self._make_proc(spec, i))
            ready = False
            prepare: Prepare | None = None
            try:
                for p in self._procs:
                    if gated and p.spec.gate:
                        self._spawn(p, gated=True)
                prepare = Prepare(plan, self._screen)  # runs while the checks run and the bus starts
                self._run_checks()
                if self._use_reaper:
                    self._reaper = Reaper()
                    self._screen.say(f"reaper pid {self._reaper.pid} will kill the nodes' process groups if this "
                                     "launcher is killed")
                    for p in self._procs:
                        if p.child is not None:
                            self._reaper.add(p.child.pid)
                bus = Bus(plan.bus_request(self._bus_override), latched_topics=plan.bus.latched,
                          hwm=plan.bus.hwm, max_msg_bytes=plan.bus.max_msg_bytes)
                self.address = bus.start()
                write_beside(plan.run_dir / "bus.address", f"{self.address}\n")  # never half an address
                if self._announce:
                    self._entry = announce(self.address, plan.run_dir)
                self._screen.say(f"bus at {self.address}; run directory {plan.run_dir}")
                self._start_observer()
                prepare.wait()
                ready = True
            finally:
                if prepare is not None and not ready:
                    prepare.cancel()
                for w in self._gates:
                    release(w, str(self.address) if ready else None)
                if self._gates and not ready:  # let them leave by themselves, saying so in their logs
                    self._run_until(lambda: not any(p.state == "running" for p in self._procs),
                                    timeout_s=_CALLED_OFF_S)
                self._gates.clear()
            if rec_spec is not None:
                self._recorder = self._make_proc(rec_spec, len(plan.nodes))
                self._start_recorder()
            if not self._stopping:
                for p in self._procs:
                    if self._stopping:
                        break
                    if p.state == "idle":  # a gated one is already running
                        self._spawn(p)
                self._all_started = True
                self._check_all_exited()
            self._run_until(lambda: self._stopping)
            self._stop(self._procs)
            self._run_until(lambda: all(p.state in ("done", "idle") for p in self._procs))
            if self._recorder is not None:
                self._stop([self._recorder])
                self._run_until(lambda: self._recorder is None or self._recorder.state in ("done", "idle"))
        finally:
            self._teardown(bus, old)
        return summarize(self._screen, self._all(), self.plan.run_dir, self._reason, self._code)

    # -- phases ----------------------------------------------------------------------------------------
    def _run_checks(self) -> None:
        """The loader's node checks the caller left to the launch (``LaunchPlan.pending_checks``), once."""
        checks, self.plan.pending_checks = self.plan.pending_checks, None
        if checks is not None:
            checks()

    def _start_observer(self) -> None:
        topic = self.plan.progress_topic
        show = self._progress_opt is not False
        if self._recorder is None and self.plan.record is None and not (topic and show) and \
                self._clock_watch is None:
            return
        self._observer.start(self.address, topic, show, self._clock_watch)

    def _start_recorder(self) -> None:
        rec = self._recorder
        if rec is None or self.plan.record is None:
            return
        self._spawn(rec)
        timeout = self.plan.record.ready_timeout_s
        heard = self._observer.heard
        ready = self._run_until(lambda: RECORDER_NAME in heard or rec.state != "running" or self._stopping,
                                timeout_s=timeout)
        if RECORDER_NAME in heard:
            self._screen.say(f"recorder ready: recording to {self.plan.run_dir / 'recording.mcap'}")
            return
        if self._stopping:
            return
        why = "exited before it was ready" if ready else f"sent no heartbeat within {timeout:g} s"
        self._request_stop(f"the recorder {why} (see {self.plan.run_dir / 'recorder.log'})", 1)

    def _stop(self, procs: list[NodeProc]) -> None:
        now = time.monotonic()
        for p in procs:
            p.begin_stop(now)

    def _run_until(self, cond: Callable[[], bool], timeout_s: float | None = None) -> bool:
        """Step the loop until ``cond()``; False if ``timeout_s`` passed first."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not cond():
            if deadline is not None and time.monotonic() >= deadline:
                return False
            self._step()
        return True

    # -- the loop --------------------------------------------------------------------------------------
    def _step(self) -> None:
        for key, _ in self._sel.select(_STEP_S):
            if key.data is None:
                self._inbox.drain()
            elif key.data is _EXITED:
                pass  # a child exited: the loop below finds which
            else:
                key.data.read(self._screen, self._sel)
        self._handle_signals()
        now = time.monotonic()
        for p in self._all():
            if p.state in ("running", "stopping") and p.child is not None and p.child.exited():
                self._on_exit(p)
            elif p.state == "stopping" and now >= p.deadline:
                p.escalate(self._screen, self._sel)
            elif p.state == "backoff" and now >= p.respawn_at and not self._stopping:
                self._spawn(p)
        if self._observer.node is not None:
            self._observer.node.spin_once(0)
        if self._clock_watch is not None and not self._stopping:  # a graph whose time stands still
            verdict, why = self._clock_watch.verdict()
            if verdict == "frozen":
                self._request_stop(why, 1)
            elif verdict == "stalled":
                self._screen.say(why, "WARNING")

    def _all(self) -> list[NodeProc]:
        return self._procs + ([self._recorder] if self._recorder is not None else [])

    def _handle_signals(self) -> None:
        while self._inbox.pending:
            sig = self._inbox.pending.pop(0)
            name = signal.Signals(sig).name
            if not self._stopping:
                stalled = self._clock_watch.stalled() if self._clock_watch is not None else ""
                self._request_stop(f"stopped by {name}" + (f" while {stalled}" if stalled else ""),
                                   1 if stalled else None)
            else:
                self._screen.say(f"{name} again: moving every stopping node on to the next signal now", "WARNING")
                for p in self._all():
                    if p.state == "stopping":
                        p.escalate(self._screen, self._sel)

    # -- children --------------------------------------------------------------------------------------
    def _make_proc(self, spec: NodeSpec, index: int) -> NodeProc:
        log = open(self.plan.run_dir / f"{spec.name}.log", "a", encoding="utf-8", buffering=1)  # noqa: SIM115
        color = self._screen.color_for(index)
        return NodeProc(spec=spec, log=log, color=color)

    def child_env(self, spec: NodeSpec) -> dict[str, str]:
        """The environment ``spec``'s process starts with (:meth:`NodeSpec.child_env`) and its key to sign its
        clock acks; the clock entry also gets the run's master key, to check them (palpa.timing.acksign)."""
        return child_env(spec, bus=self.address, run_dir=self.plan.run_dir, python_path=self.plan.python_path,
                         clock_master=self._clock_master)

    def _spawn(self, p: NodeProc, gated: bool = False) -> None:
        spec = p.spec
        env = self.child_env(spec)
        argv = spec.argv()
        p.starts += 1
        p.started_at = time.monotonic()
        p.buf = b""
        try:
            p.child, w = start_child(argv, env, gated=gated)
        except OSError as exc:
            p.child = None
            self._screen.say(f"cannot start {spec.name}: {argv[0]}: {exc.strerror or exc}", "ERROR")
            p.state = "running"
            self._after_exit(p, 127)
            return
        if gated:
            self._gates.append(w)
        p.state = "running"
        if self._reaper is not None and not self._reaper.add(p.child.pid):
            self._screen.say("the reaper process is gone: a killed launcher may leave grandchildren behind", "WARNING")
            self._reaper = None
        self._sel.register(p.child.fd, selectors.EVENT_READ, p)
        if p.child.exit_fd is not None:
            self._sel.register(p.child.exit_fd, selectors.EVENT_READ, _EXITED)
        again = f" (start {p.starts})" if p.starts > 1 else ""
        p.log.write(f"[launch] started pid {p.child.pid}{again}: {' '.join(argv)}\n")
        self._screen.say(f"started {spec.name} pid {p.child.pid}{again}")

    def _on_exit(self, p: NodeProc) -> None:
        child = p.child
        if child is None or child.returncode is None:
            return
        p.drop_output(self._screen, self._sel)
        self._forget_exit_fd(child)
        if self._reaper is not None:
            self._reaper.remove(child.pid)
        code = child.returncode
        p.log.write(f"[launch] pid {child.pid} ended: {exit_text(code)}\n")
        if p.state == "stopping":
            ended_when_asked(p, code, self._screen)
            return
        if self._stopping:
            p.state, p.outcome = "done", f"exited while stopping ({exit_text(code)})"
            return
        self._after_exit(p, code)

    def _forget_exit_fd(self, child: Child) -> None:
        if child.exit_fd is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(child.exit_fd)
            child.close_exit_fd()

    def _after_exit(self, p: NodeProc, code: int) -> None:
        """A node ended on its own: respawn it, end the launch, or carry on without it (palpa.launch.exits)."""
        record_required = self.plan.record is not None and self.plan.record.required
        stop = ended_by_itself(p, code, self._screen, recorder=p is self._recorder, record_required=record_required)
        if stop is not None:
            self._request_stop(*stop)
        if p.state != "backoff":  # a respawn is pending: the node has not ended for good
            self._check_all_exited()

    def _check_all_exited(self) -> None:
        if self._all_started and not self._stopping and all(p.state == "done" for p in self._procs):
            self._request_stop("every node has ended", None)

    def _request_stop(self, reason: str, code: int | None) -> None:
        if self._stopping:
            return
        self._stopping, self._reason, self._code = True, reason, code
        self._screen.say(f"stopping: {reason}", "WARNING" if code else "INFO")

    # -- teardown ----------------------------------------------------------------------------------------
    def _teardown(self, bus: Bus | None, old: dict[int, Any]) -> None:
        # only reached with children still running if something raised: do not leave them behind
        for p in self._all():
            p.kill_now()
            if p.child is not None:
                self._forget_exit_fd(p.child)
        had_view = self._screen.view is not None
        self._screen.close_view()  # the summary goes to stderr like every launcher message
        if had_view:
            report_hidden(self._screen, self._all(), self.plan.progress_report)
        if self._entry is not None:
            withdraw(self._entry)
        if self._observer.node is not None:
            self._observer.node.close(0)
        if bus is not None:
            bus.stop()
        if self._reaper is not None:
            self._reaper.close()
        self._inbox.restore(old)
        for p in self._all():
            p.log.close()
        self._sel.close()
        self._inbox.close()

