"""The supervisor's record of one launched node (or the recorder), and its output.

A :class:`NodeProc` holds what the supervisor knows of a node: its spec, its log file, the running
:class:`~palpa.launch.process.Child` if any, its state (idle, running, backoff, stopping, done), its starts and
failures, the stop stage it has reached and its outcome in words. Its output arrives as bytes from the child's
pipe; here it is split into lines (a partial line waits for the rest, a line longer than 64 KiB is cut), and each
line goes to the node's log, to the screen (:class:`~palpa.launch.output.Screen` decides what shows), to the tail
kept to show after a failure, and, when the progress bar kept it off the screen, to the lines reported under the
bar at the end. Its staged stop: SIGINT, then SIGTERM after the spec's ``sigterm_timeout``, then SIGKILL after
its ``sigkill_timeout``. Split from palpa.launch.supervisor, which decides when to read, respawn and stop.
"""

from __future__ import annotations

import contextlib
import selectors
import signal
import subprocess
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TextIO

from palpa.launch.output import Screen
from palpa.launch.plan import VIZ_READY, VIZ_TARGET, NodeSpec
from palpa.launch.process import Child

__all__ = ["REAP_GRACE_S", "NodeProc"]

REAP_GRACE_S = 3.0  # after SIGKILL, how long to wait for the kernel before giving up on a process

_MAX_LINE = 65536
_REPORT_LINES = 40  # a composed process's lines are every member's: room for the reported one's
_WHY_CHARS = 300


@dataclass
class NodeProc:
    spec: NodeSpec
    log: TextIO
    color: str = ""
    child: Child | None = None
    state: str = "idle"  # idle | running | backoff | stopping | done
    starts: int = 0
    failures: int = 0  # consecutive exits that were answered by a respawn
    started_at: float = 0.0
    respawn_at: float = 0.0
    stage: int = 0  # while stopping: 1 SIGINT sent, 2 SIGTERM sent, 3 SIGKILL sent
    deadline: float = 0.0
    buf: bytes = b""
    tail: deque[str] = field(default_factory=lambda: deque(maxlen=15))
    hidden: deque[str] = field(default_factory=lambda: deque(maxlen=_REPORT_LINES))
    """Lines the progress bar kept off the screen (for ``progress: {report: [...]}``)."""
    outcome: str = "not started"
    failed: bool = False
    why: str = ""
    """Why it failed in its own words: its last ERROR line (for the summary), '' if it said none."""
    escalated: str | None = None
    error_line: str = ""
    """Its last ERROR or CRITICAL line, without the level: kept apart from the tail, since a traceback printed
    after it (a helper of the node's dying on the same Ctrl-C) may push it out of the tail."""

    def last_error(self) -> str:
        """Its last ERROR or CRITICAL log line, without the level ('' if none), cut to 300 characters: what the
        summary gives as the reason it failed."""
        rest = self.error_line
        return rest if len(rest) <= _WHY_CHARS else rest[:_WHY_CHARS - 3] + "..."

    def read(self, screen: Screen, sel: selectors.BaseSelector) -> None:
        """Take what the pipe has now (the selector said it is readable); at its end, :meth:`drop_output`."""
        if self.child is None:
            return
        data = self.child.read()
        if data is None:
            self.drop_output(screen, sel)
            return
        self.take(data, screen)

    def line(self, text: str, screen: Screen) -> None:
        """One whole line of output: to the log, the tail, the screen or the lines hidden under the bar."""
        with contextlib.suppress(OSError, ValueError):
            self.log.write(text + "\n")
        self.tail.append(text)
        level, _, rest = text.partition(" ")
        if level in ("ERROR", "CRITICAL") and rest:
            self.error_line = rest
        if self.spec.target == VIZ_TARGET and text.startswith(VIZ_READY):
            url = text[len(VIZ_READY):].split(" ", 1)[0]
            screen.say(f"Foxglove: open {url} in the Foxglove app (Open connection -> Foxglove WebSocket; "
                       "docs/foxglove.md)", "NOTICE")
        if not screen.node_line(self.spec.name, self.color, self.spec.output, text) and self.spec.output == "screen":
            self.hidden.append(text)

    def take(self, data: bytes, screen: Screen) -> None:
        """Bytes from the pipe: every line they complete; the rest waits in :attr:`buf`."""
        buf = self.buf + data
        *lines, rest = buf.split(b"\n")
        for raw in lines:
            self.line(raw.decode("utf-8", errors="replace").rstrip("\r"), screen)
        if len(rest) > _MAX_LINE:
            self.line(rest.decode("utf-8", errors="replace"), screen)
            rest = b""
        self.buf = rest

    def drop_output(self, screen: Screen, sel: selectors.BaseSelector) -> None:
        """Read what is left in the pipe, flush a last partial line, stop watching the pipe."""
        if self.child is None:
            return
        for _ in range(64):
            data = self.child.read()
            if not data:
                break
            self.take(data, screen)
        if self.buf:
            self.line(self.buf.decode("utf-8", errors="replace"), screen)
            self.buf = b""
        with contextlib.suppress(KeyError, ValueError):
            sel.unregister(self.child.fd)
        self.child.close_output()

    # -- the staged stop ---------------------------------------------------------------------------------
    def begin_stop(self, now: float) -> None:
        """The launch is stopping: SIGINT to a running node (its ``sigterm_timeout`` from ``now``); a node waiting
        to be respawned is not."""
        if self.state == "running" and self.child is not None:
            self.state, self.stage = "stopping", 1
            self.deadline = now + self.spec.sigterm_timeout
            self.child.signal(signal.SIGINT)
        elif self.state == "backoff":
            self.state, self.outcome = "done", self.outcome + "; not respawned (launch stopping)"

    def escalate(self, screen: Screen, sel: selectors.BaseSelector) -> None:
        """The node did not stop in time (or a second Ctrl-C came): SIGTERM after SIGINT, SIGKILL after SIGTERM;
        still there :data:`REAP_GRACE_S` after SIGKILL, it is given up on."""
        if self.child is None:
            return
        now = time.monotonic()
        name = self.spec.name
        if self.stage == 1:
            screen.say(f"{name} did not stop within {self.spec.sigterm_timeout:g} s of SIGINT: sending SIGTERM",
                       "WARNING")
            self.stage, self.deadline, self.escalated = 2, now + self.spec.sigkill_timeout, "SIGTERM"
            self.child.signal(signal.SIGTERM)
        elif self.stage == 2:
            screen.say(f"{name} did not stop within {self.spec.sigkill_timeout:g} s of SIGTERM: sending SIGKILL",
                       "WARNING")
            self.stage, self.deadline, self.escalated = 3, now + REAP_GRACE_S, "SIGKILL"
            self.child.signal(signal.SIGKILL)
        else:
            screen.say(f"{name} (pid {self.child.pid}) is still there {REAP_GRACE_S:g} s after SIGKILL "
                       "(stuck in the kernel?); giving up on it", "ERROR")
            self.drop_output(screen, sel)
            self.state, self.outcome, self.failed = "done", "could not be stopped", True

    def kill_now(self) -> None:
        """SIGKILL the node if it is still there, wait for it (at most :data:`REAP_GRACE_S`), and count it failed:
        the launcher's teardown after an error of its own, which must not leave the node behind."""
        if self.state in ("running", "stopping") and self.child is not None and not self.child.exited():
            self.child.signal(signal.SIGKILL)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.child.popen.wait(REAP_GRACE_S)
            self.child.exited()
            self.state, self.outcome, self.failed = "done", "killed (launcher error)", True
