"""How signals reach the launcher's loop, which runs on one thread and sleeps in a selector.

The handlers (SIGINT, SIGTERM, SIGHUP; installed only on the main thread) only queue the signal's number; the
signal module's wake-up fd writes a byte to a socket pair the loop's selector watches, so the loop wakes at once
and handles the queue itself, outside the handler. :meth:`SignalInbox.push` does the same from any thread (the
supervisor's ``request_stop``). Split from palpa.launch.supervisor, which decides what a signal means.
"""

from __future__ import annotations

import contextlib
import selectors
import signal
import socket
import threading
from types import FrameType
from typing import Any

__all__ = ["SignalInbox"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class SignalInbox:
    """The signals received and not yet handled (:attr:`pending`, oldest first), and the wake-up socket pair."""

    def __init__(self) -> None:
        self.pending: list[int] = []
        self._wake_r, self._wake_w = socket.socketpair()
        for s in (self._wake_r, self._wake_w):
            s.setblocking(False)

    def push(self, sig: int) -> None:
        """Queue ``sig`` as if it had been received, and wake the loop (safe from other threads and handlers)."""
        self.pending.append(sig)
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    def install(self, sel: selectors.BaseSelector) -> dict[int, Any]:
        """Install the handlers and the wake-up fd, watched by ``sel`` with data None; returns what to restore
        (empty off the main thread: an embedded supervisor is stopped by its caller with request_stop())."""
        old: dict[int, Any] = {}
        if threading.current_thread() is not threading.main_thread():
            return old  # embedded use: the caller stops us with request_stop()

        def on_signal(signum: int, frame: FrameType | None) -> None:
            self.pending.append(signum)

        for sig in _SIGNALS:
            old[sig] = signal.signal(sig, on_signal)
        old[-1] = signal.set_wakeup_fd(self._wake_w.fileno(), warn_on_full_buffer=False)
        sel.register(self._wake_r.fileno(), selectors.EVENT_READ, None)
        return old

    def drain(self) -> None:
        """Empty the wake-up socket (the selector said it is readable)."""
        try:
            while self._wake_r.recv(4096):
                pass
        except OSError:
            pass

    @staticmethod
    def restore(old: dict[int, Any]) -> None:
        """Put back the handlers and the wake-up fd that :meth:`install` replaced."""
        if -1 in old:
            signal.set_wakeup_fd(old.pop(-1))
        for sig, handler in old.items():
            signal.signal(sig, handler)

    def close(self) -> None:
        self._wake_r.close()
        self._wake_w.close()
