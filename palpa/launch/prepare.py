"""A launch file's ``prepare`` commands: run in order before any node builds, the first that fails ends the launch.

They start as soon as the launcher has read the file, and run while it checks the node classes' parameters and
starts its bus: a composed simulation waits at its start gate for all three, and on two cores the ~0.2 s of a
Python prepare step need not follow the checks. A launch that gives up meanwhile (a check failed, Ctrl-C) stops
the command running (SIGTERM, then SIGKILL) and starts no other.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from typing import IO

from palpa.errors import LaunchError
from palpa.launch.output import Screen
from palpa.launch.plan import LaunchPlan

__all__ = ["Prepare"]

PREPARE_TIMEOUT_S = 120.0
"""Wall seconds one prepare command may take."""
_STOP_GRACE_S = 2.0


class Prepare:
    """The prepare commands of one launch, the first already started (``python`` meaning this interpreter, the
    file's ``python_path`` first on PYTHONPATH). :meth:`wait` runs the rest in order; :meth:`cancel` stops them."""

    def __init__(self, plan: LaunchPlan, screen: Screen) -> None:
        self._screen = screen
        self._env = dict(os.environ)
        if plan.python_path:
            self._env["PYTHONPATH"] = os.pathsep.join([*plan.python_path,
                                                       *filter(None, [self._env.get("PYTHONPATH")])])
        self._todo = [list(argv) for argv in plan.prepare]
        self._proc: subprocess.Popen[bytes] | None = None
        self._out: IO[bytes] | None = None
        self._argv: list[str] = []
        self._started = 0.0
        self._next()

    def _next(self) -> bool:
        """Start the next command; False when none is left."""
        if not self._todo:
            return False
        argv = self._argv = self._todo.pop(0)
        cmd = [sys.executable, *argv[1:]] if argv[0] == "python" else argv
        self._screen.say(f"prepare: {' '.join(argv)}")
        # a file, not a pipe: a talkative command never waits for us to read; closed by _close_out
        self._out = tempfile.TemporaryFile()  # noqa: SIM115
        try:
            self._proc = subprocess.Popen(cmd, env=self._env, stdin=subprocess.DEVNULL, stdout=self._out,
                                          stderr=subprocess.STDOUT)
        except OSError as exc:
            self._close_out()
            raise LaunchError(f"prepare: {' '.join(argv)}: {exc}") from None
        self._started = time.monotonic()
        return True

    def wait(self) -> None:
        """Run every command to its end, in order; a :class:`LaunchError` with the command and the last lines it
        printed for the first that fails or outlives :data:`PREPARE_TIMEOUT_S`."""
        while self._proc is not None:
            proc, argv = self._proc, self._argv
            try:
                code = proc.wait(timeout=max(0.0, PREPARE_TIMEOUT_S - (time.monotonic() - self._started)))
            except subprocess.TimeoutExpired:
                self.cancel()
                raise LaunchError(f"prepare: {' '.join(argv)}: timed out after {PREPARE_TIMEOUT_S:g} s") from None
            self._proc = None
            tail = self._tail()
            if code != 0:
                self._todo.clear()
                raise LaunchError(f"prepare: {' '.join(argv)} exited {code}: {' / '.join(tail)}")
            self._next()

    def cancel(self) -> None:
        """Stop the command running, if any, and start no other."""
        self._todo.clear()
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=_STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self._close_out()

    def _tail(self) -> list[str]:
        out = self._out
        if out is None:
            return []
        out.seek(0)
        text = out.read().decode(errors="replace")
        self._close_out()
        return text.strip().splitlines()[-5:]

    def _close_out(self) -> None:
        if self._out is not None:
            with contextlib.suppress(OSError):
                self._out.close()
            self._out = None
