"""What a closed socket still holds leaves before the process exits.

Closing a ZeroMQ socket only hands its queue to libzmq's I/O thread, and that thread dies with the process: a node
that publishes a burst and exits (``palpa run``, a script, a tool) would lose the tail of it, silently, since no
sequence gap shows a loss at the end of a stream (bench/multihost.py lost up to 45 % of a burst across hosts).
Terminating the context is what waits for the sockets' linger. The shared context is terminated at interpreter
exit, after the longest linger a transport asked for, in a thread with a deadline: a socket someone left open would
otherwise block the exit forever.
"""

from __future__ import annotations

import atexit
import threading

import zmq

__all__ = ["note_linger"]

_linger_ms = 0
_registered = False


def note_linger(ctx: zmq.Context[zmq.Socket[bytes]], linger_ms: int) -> None:
    """A transport on ``ctx`` closed its sockets with ``linger_ms``: wait for them at exit when ``ctx`` is the
    shared instance (a context of one's own is one's own to terminate)."""
    global _linger_ms, _registered
    if linger_ms <= 0 or ctx is not zmq.Context.instance():
        return
    _linger_ms = max(_linger_ms, linger_ms)
    if not _registered:
        _registered = True
        atexit.register(_flush)


def _flush() -> None:
    flusher = threading.Thread(target=zmq.Context.instance().term, name="palpa-exit-flush", daemon=True)
    flusher.start()
    flusher.join(_linger_ms / 1000 + 1.0)
