"""Child processes for tests: output captured to files, waits with deadlines, always cleaned up."""

from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypeVar

from emulators.ur.process import UrEmulatorProcess
from palpa.net.address import BusAddress

T = TypeVar("T")
REPO = Path(__file__).resolve().parent.parent


def bench_module(name: str) -> ModuleType:
    """``bench/NAME.py`` imported as a module (bench/ is scripts, not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def palpa_cmd(*args: str) -> list[str]:
    """The ``palpa`` command line as this interpreter runs it (children inherit PYTHONPATH)."""
    return [sys.executable, "-m", "palpa.cli.main", *args]


def short_ipc_base() -> str:
    """A fresh ipc base path well under the 107-character limit (pytest's tmp dirs are too long)."""
    return f"/tmp/pt-{os.getpid()}-{secrets.token_hex(3)}"


def bus_spec(transport: str) -> BusAddress:
    """A bus address of one transport: ipc under a short path, or tcp on OS-chosen loopback ports."""
    if transport == "ipc":
        return BusAddress.parse(f"ipc://{short_ipc_base()}")
    return BusAddress("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*")


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class Proc:
    """One child process whose stdout+stderr go to a file that tests can poll."""

    def __init__(self, cmd: Sequence[str], env: dict[str, str] | None, cwd: str | None,
                 ignore_sigint: bool = False) -> None:
        fd, name = tempfile.mkstemp(prefix="palpa-test-", suffix=".log")
        self.log_path = Path(name)
        self._log = os.fdopen(fd, "wb")
        self.cmd = list(cmd)
        self.popen = subprocess.Popen(
            self.cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env, cwd=cwd, start_new_session=True,
            preexec_fn=_ignore_sigint if ignore_sigint else None,
        )

    @property
    def pid(self) -> int:
        return self.popen.pid

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for_output(self, needle: str, timeout: float = 10.0) -> str:
        """Wait until ``needle`` appears in the output; return the line. Fails with the output on timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self.output().splitlines():
                if needle in line:
                    return line
            if self.popen.poll() is not None:
                raise AssertionError(f"{self.cmd} exited {self.popen.returncode} before {needle!r}:\n{self.output()}")
            time.sleep(0.02)
        raise AssertionError(f"timed out waiting for {needle!r} from {self.cmd}:\n{self.output()}")

    def first_line(self, timeout: float = 10.0) -> str:
        """The first complete line of output (waits for it, bounded)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            out = self.output()
            if "\n" in out:
                return out.split("\n", 1)[0].strip()
            if self.popen.poll() is not None:
                raise AssertionError(f"{self.cmd} exited {self.popen.returncode} before printing a line:\n{out}")
            time.sleep(0.02)
        raise AssertionError(f"timed out waiting for a line from {self.cmd}:\n{self.output()}")

    def signal(self, sig: int) -> None:
        if self.popen.poll() is None:
            os.kill(self.popen.pid, sig)

    def wait(self, timeout: float) -> int:
        try:
            return self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.cmd} did not exit within {timeout} s:\n{self.output()}") from None

    def stop(self, timeout: float = 5.0) -> int:
        """SIGINT, then wait (bounded); returns the exit code."""
        self.signal(signal.SIGINT)
        return self.wait(timeout)


class ProcessGroup:
    def __init__(self) -> None:
        self.procs: list[Proc] = []

    def start(self, cmd: Sequence[str], env: dict[str, str] | None = None, cwd: str | None = None,
              ignore_sigint: bool = False) -> Proc:
        """Start ``cmd`` in its own session; ``ignore_sigint`` starts it with SIGINT ignored, as a shell does
        for a background job."""
        p = Proc(cmd, env, cwd, ignore_sigint)
        self.procs.append(p)
        return p

    def cleanup(self) -> None:
        for p in self.procs:
            if p.popen.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.popen.pid, signal.SIGKILL)
                p.popen.wait(5)
            p._log.close()
            p.log_path.unlink(missing_ok=True)


def wait_until(cond: Callable[[], T | None], timeout: float = 10.0, what: str = "condition",
               step: Callable[[], object] | None = None) -> T:
    """Poll ``cond`` until it returns something truthy, and return that; ``step`` runs between polls (a node's
    ``spin_once``, or a publish that is repeated until a late joiner hears it), else a 10 ms sleep. The one wait
    helper of the tests: raises AssertionError naming ``what`` at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        got = cond()
        if got:
            return got
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        if step is not None:
            step()
        else:
            time.sleep(0.01)


def drain(sub: Any) -> list[Any]:
    """Everything queued on a subscription (``palpa.Subscription``), oldest first; the queue is left empty."""
    out = []
    while sub.queue:
        out.append(sub.queue.popleft())
    return out


@contextlib.contextmanager
def _gc_frozen() -> Iterator[list[float]]:
    """The test worker's heap (every earlier test's objects) frozen out of the collector while a real-time test runs,
    and the pauses of the collections that still happen (s), to print: a full collection over a large heap holds
    the GIL for tenths of a second on a loaded machine, and the driver's RTDE watchdog kicks, in this process, with
    it (the watchdog allows 0.5 s). A rig's scanner runs in its own small process."""
    pauses: list[float] = []
    started: list[float] = []

    def timed(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            started[:] = [time.perf_counter()]
        elif started:
            pauses.append(time.perf_counter() - started[0])

    gc.collect()
    gc.freeze()
    gc.callbacks.append(timed)
    try:
        yield pauses
    finally:
        gc.callbacks.remove(timed)
        gc.unfreeze()


EMULATOR_START_S = 10.0
"""How long the driver gives the emulator to start an uploaded path. A controller starts it within a few 2 ms cycles
(the driver's 2 s default); the emulator is a Python process that two busy cores may not run for seconds, so its
delay would be reported as a path that never started (the timeout itself: the last test of this file)."""


@contextlib.contextmanager
def ur_emulator(args: Sequence[str]) -> Iterator[UrEmulatorProcess]:
    """A UR emulator process on a random loopback address, stopped at the end; it must exit 0 (its log is printed,
    so pytest shows it when the test failed, with the longest garbage-collection pause of this process meanwhile:
    :func:`_gc_frozen`)."""
    with _gc_frozen() as pauses:
        proc = UrEmulatorProcess.on_random_loopback(list(args))
        proc.start()
        try:
            yield proc
        finally:
            code = proc.stop()
            print(proc.log())
            print(f"this process: {len(pauses)} garbage collections while the emulator ran, the longest "
                  f"{max(pauses, default=0.0):.3f} s")
            assert code == 0, f"emulator exited with {code}"


class ChildSteps:
    """A spawned child process that talks with the test in words over a pipe: ``target(*args, pipe)`` sends a word
    once it has done a step and waits for the test's (``tell``). For code that can abort the process it runs in
    (ur_rtde's reconnect thread on a dropped connection): an abort fails the test that ran it, not the xdist worker.
    Use as a context manager; on leaving it the child must have exited 0."""

    def __init__(self, target: Callable[..., None], *args: Any, what: str = "the child") -> None:
        ctx = multiprocessing.get_context("spawn")
        self._ours, theirs = ctx.Pipe()
        self.what = what
        self.child = ctx.Process(target=target, args=(*args, theirs), daemon=True)

    def __enter__(self) -> ChildSteps:
        self.child.start()
        return self

    def said(self, word: str, timeout_s: float, what: str) -> None:
        """Wait (at most ``timeout_s``) for the child to say ``word``; a child that died fails at once."""

        def heard() -> bool:
            assert self.child.is_alive() or self._ours.poll(), f"{self.what} died (exit code {self.child.exitcode})"
            return bool(self._ours.poll(0.05)) and self._ours.recv() == word

        wait_until(heard, timeout_s, what)

    def tell(self, word: str) -> None:
        self._ours.send(word)

    def __exit__(self, *exc: object) -> None:
        self.child.join(5.0)
        if self.child.is_alive():
            self.child.kill()
            self.child.join(5.0)
        if exc[0] is None:
            assert self.child.exitcode == 0, f"{self.what} exited with {self.child.exitcode} (-6: ur_rtde aborted)"


if TYPE_CHECKING:
    import zmq


def replies_until_pong(sock: zmq.Socket[bytes], token: bytes = b"sync") -> list[list[bytes]]:
    """Every reply of the bus's latch socket before the PONG to a PING sent now (it answers in order); fails when no
    PONG comes within 5 s (its cache thread died)."""
    sock.send_multipart([b"PING", token])
    out = []
    while True:
        assert sock.poll(5000), f"no PONG {token!r} within 5 s: the bus's cache thread does not answer"
        frames = sock.recv_multipart()
        if frames == [b"PONG", token]:
            return out
        out.append(frames)
