"""Run the UR emulator in a child process and drive it from tests.

Needed because ur_rtde's Python bindings hold the GIL while they block (connecting, waiting
for the control script, moveL handshakes): an emulator thread in the same process would be
starved and the client would wait for it forever.

    with UrEmulatorProcess.on_random_loopback() as emu:
        rtde_c = rtde_control.RTDEControlInterface(emu.host)
        emu.command("pstop")                      # fault injection while it runs
"""

from __future__ import annotations

import json
import queue
import random
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from types import TracebackType
from typing import IO, Any


class EmulatorProcessError(RuntimeError):
    """The emulator process failed to start, answer, or stop in time."""


class UrEmulatorProcess:
    """`python -m emulators.ur --control` on `host`; ready when `start()` returns."""

    def __init__(self, host: str, extra_args: Sequence[str] = (), *, start_timeout_s: float = 30.0,
                 reply_timeout_s: float = 5.0) -> None:
        self.host = host
        self.extra_args = list(extra_args)
        self.start_timeout_s, self.reply_timeout_s = start_timeout_s, reply_timeout_s
        self.ports: dict[str, int] = {}
        self._proc: subprocess.Popen[str] | None = None
        self._lines: queue.Queue[str | None] = queue.Queue()
        self.stderr_tail: deque[str] = deque(maxlen=400)
        self._readers: list[threading.Thread] = []
        self._cmd_lock = threading.Lock()

    @classmethod
    def on_random_loopback(cls, extra_args: Sequence[str] = (), **kwargs: float) -> UrEmulatorProcess:
        """An emulator on a random 127.x.y.z address (never 127.0.0.1), ready to start."""
        rng = random.SystemRandom()
        host = f"127.{rng.randint(1, 254)}.{rng.randint(0, 255)}.{rng.randint(2, 254)}"
        return cls(host, extra_args, **kwargs)

    def start(self) -> UrEmulatorProcess:
        cmd = [sys.executable, "-u", "-m", "emulators.ur", "--control", "--host", self.host, *self.extra_args]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True, bufsize=1)
        pipes = (self._proc.stdout, self._proc.stderr)
        if pipes[0] is None or pipes[1] is None:
            raise EmulatorProcessError("emulator process started without pipes")
        self._readers = [
            threading.Thread(target=self._pump, args=(pipes[0], True), name="urfake-stdout", daemon=True),
            threading.Thread(target=self._pump, args=(pipes[1], False), name="urfake-stderr", daemon=True),
        ]
        for t in self._readers:
            t.start()
        line = self._next_line(self.start_timeout_s, "start")
        if not line.startswith("READY "):
            self.stop()
            raise EmulatorProcessError(f"emulator on {self.host} did not start: {line!r}\n{self.log()}")
        self.ports = json.loads(line[6:])["ports"]
        return self

    def command(self, line: str) -> dict[str, Any]:
        """Send one control command (see emulators.ur.__main__) and return its JSON answer."""
        if self._proc is None or self._proc.stdin is None:
            raise EmulatorProcessError("emulator process is not running")
        with self._cmd_lock:
            self._proc.stdin.write(line.strip() + "\n")
            self._proc.stdin.flush()
            answer: dict[str, Any] = json.loads(self._next_line(self.reply_timeout_s, line))
        if "error" in answer:
            raise EmulatorProcessError(f"emulator command {line!r} failed: {answer['error']}")
        return answer

    def state(self) -> dict[str, Any]:
        return self.command("state")

    def wait_state(self, predicate: Any, timeout_s: float, poll_s: float = 0.01) -> dict[str, Any]:
        """Poll `state()` until `predicate(state)` holds; raise with the last state on timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            st = self.state()
            if predicate(st):
                return st
            if time.monotonic() > deadline:
                raise EmulatorProcessError(f"emulator state condition not met within {timeout_s} s: {st}")
            time.sleep(poll_s)

    def log(self) -> str:
        return "\n".join(self.stderr_tail)

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """Ask the emulator to quit, then terminate/kill on deadlines; returns its exit code."""
        proc, self._proc = self._proc, None
        if proc is None:
            return None
        try:
            if proc.stdin is not None:
                proc.stdin.write("quit\n")
                proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            pass
        for action in (None, proc.terminate, proc.kill):
            if action is not None:
                action()
            try:
                proc.wait(timeout_s)
                break
            except subprocess.TimeoutExpired:
                continue
        for t in self._readers:
            t.join(timeout_s)
        return proc.returncode

    def __enter__(self) -> UrEmulatorProcess:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def _pump(self, stream: IO[str], is_stdout: bool) -> None:
        for line in stream:
            if is_stdout:
                self._lines.put(line.rstrip("\n"))
            else:
                self.stderr_tail.append(line.rstrip("\n"))
        if is_stdout:
            self._lines.put(None)

    def _next_line(self, timeout_s: float, what: str) -> str:
        try:
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise EmulatorProcessError(f"emulator on {self.host}: no answer to {what!r} within {timeout_s} s\n{self.log()}") from None
        if line is None:
            raise EmulatorProcessError(f"emulator on {self.host} exited (while waiting for {what!r})\n{self.log()}")
        return line
