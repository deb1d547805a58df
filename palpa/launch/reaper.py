"""A watchdog process that kills the launcher's process groups if the launcher dies without cleaning up.

PR_SET_PDEATHSIG kills each *direct* child when the launcher dies, even by SIGKILL; it is not inherited across
fork, so a node's own children (a shell script's programs, say) would survive. The reaper covers them: the
launcher starts it once, in its own session, with a pipe on its stdin, and writes ``+PGID`` / ``-PGID`` lines as
node process groups come and go. When the pipe reaches end-of-file — the launcher exited, however it exited —
the reaper sends SIGKILL to every group still registered and exits. A process that leaves its group (setsid) is
beyond it.

This file is run by path (``python reaper.py``) so it imports nothing but the standard library.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys

__all__ = ["Reaper"]


class Reaper:
    """The launcher's end: start the watchdog, register and unregister process groups, close at the end."""

    def __init__(self) -> None:
        self.popen = subprocess.Popen(
            [sys.executable, "-S", os.path.abspath(__file__)], stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, close_fds=True,
        )
        self._broken = False

    @property
    def pid(self) -> int:
        return self.popen.pid

    def _send(self, line: str) -> bool:
        stdin = self.popen.stdin
        if self._broken or stdin is None:
            return False
        try:
            stdin.write(line.encode())
            stdin.flush()
            return True
        except (BrokenPipeError, ValueError, OSError):
            self._broken = True
            return False

    def add(self, pgid: int) -> bool:
        """Watch a process group; False if the reaper is gone."""
        return self._send(f"+{pgid}\n")

    def remove(self, pgid: int) -> bool:
        """Forget a process group (its leader has been reaped)."""
        return self._send(f"-{pgid}\n")

    def close(self, timeout_s: float = 2.0) -> None:
        """End the reaper (it kills whatever is still registered) and wait for it, bounded."""
        if self.popen.stdin is not None:
            with contextlib.suppress(OSError):
                self.popen.stdin.close()
        try:
            self.popen.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait(timeout_s)


def _main() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)  # only the launcher's end of the pipe decides when we act
    groups: set[int] = set()
    for line in sys.stdin.buffer:
        try:
            pgid = int(line[1:])
        except ValueError:
            continue
        if line.startswith(b"+"):
            groups.add(pgid)
        elif line.startswith(b"-"):
            groups.discard(pgid)
    for pgid in groups:
        with contextlib.suppress(OSError):
            os.killpg(pgid, signal.SIGKILL)


if __name__ == "__main__":
    _main()
