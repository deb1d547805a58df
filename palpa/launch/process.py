"""Child processes of the launcher: each in its own process group, killed with the launcher, stopped in stages.

``PR_SET_PDEATHSIG`` (Linux) makes the kernel send SIGKILL to a child when the *thread* that forked it exits, so
children must be spawned from a thread that lives as long as the launcher (we use the main thread). The setting
survives ``exec``; the child checks ``getppid()`` right after setting it, in case the launcher died in between.
Grandchildren are not covered by it: when a child's group leader exits, the launcher kills what is left of the
group (see :meth:`Child.exited`).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["Child", "pdeathsig_supported", "process_alive"]

_PR_SET_PDEATHSIG = 1

try:
    _libc: ctypes.CDLL | None = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None
    _prctl = _libc.prctl if _libc is not None else None
except (OSError, AttributeError):  # pragma: no cover - non-glibc systems
    _libc = None
    _prctl = None


def pdeathsig_supported() -> bool:
    """True where children die with the launcher by PR_SET_PDEATHSIG (Linux)."""
    return _prctl is not None


def _child_setup(launcher_pid: int) -> Callable[[], None]:
    # Runs in the forked child before exec: only async-signal-safe libc calls, no allocation-heavy Python.
    prctl = _prctl

    def setup() -> None:
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        if os.getppid() != launcher_pid:  # the launcher died before the prctl took effect
            os.kill(os.getpid(), signal.SIGKILL)

    return setup


class Child:
    """One running child process with its output pipe (stdout and stderr merged, non-blocking)."""

    def __init__(self, argv: Sequence[str], env: dict[str, str], cwd: Path | None = None,
                 pass_fds: Sequence[int] = ()) -> None:
        self.popen = subprocess.Popen(
            list(argv), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
            cwd=cwd, start_new_session=True, preexec_fn=_child_setup(os.getpid()), bufsize=0, close_fds=True,
            pass_fds=tuple(pass_fds),
        )
        self.pid = self.popen.pid
        out = self.popen.stdout
        if out is None:  # pragma: no cover - stdout=PIPE always gives one
            raise RuntimeError("no output pipe")
        self._out = out
        self.fd = self._out.fileno()
        os.set_blocking(self.fd, False)
        self.returncode: int | None = None
        self.exit_fd: int | None = None
        """A pidfd, readable once the child has exited (Linux 5.3+; None elsewhere): a selector then wakes at its
        exit, which its output's end does not say (a grandchild may hold the pipe, or the pipe closes first)."""
        with contextlib.suppress(AttributeError, OSError):
            self.exit_fd = os.pidfd_open(self.pid)

    def signal(self, sig: int) -> bool:
        """Send ``sig`` to the child's whole process group; False if it is already gone."""
        if self.returncode is not None:
            return False
        try:
            os.killpg(self.pid, sig)
            return True
        except ProcessLookupError:
            return False
        except PermissionError:
            try:
                os.kill(self.pid, sig)
                return True
            except ProcessLookupError:
                return False

    def exited(self) -> bool:
        """Check (without blocking) whether the child has exited; if so, kill any process left in its group,
        reap it and set :attr:`returncode` (negative: killed by that signal)."""
        if self.returncode is not None:
            return True
        try:
            # WNOWAIT: leave it a zombie, so its pid (= our process group id) cannot be reused while we
            # clean up the group
            info = os.waitid(os.P_PID, self.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            info = None
            if self.popen.poll() is None:
                return False
        else:
            if info is None:
                return False
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.pid, signal.SIGKILL)
        self.returncode = self.popen.wait()
        return True

    def read(self) -> bytes | None:
        """Whatever output is ready (b"" if none now); None at end of output."""
        try:
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return b""
        except OSError:
            return None
        return data if data else None

    def close_exit_fd(self) -> None:
        """Close :attr:`exit_fd` (unregister it from any selector first)."""
        fd, self.exit_fd = self.exit_fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)

    def close_output(self) -> None:
        with contextlib.suppress(OSError):
            self._out.close()


def process_alive(pid: int) -> bool:
    """True if ``pid`` is a live process (a zombie counts as dead)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
    except FileNotFoundError:
        return False
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True
    state = stat.rsplit(b")", 1)[1].split()[0]
    return state not in (b"Z", b"X")
