"""Watching a node's handshakes with the bus: a CURVE refusal is logged, and retried.

libzmq ends a connection whose handshake the server refused (ZAP) and never tries it again; a key authorised
later (``palpa bus`` rereads its client keys on SIGHUP) would then never let the node in. :class:`HandshakeWatch`
keeps a monitor on the node's publisher socket while it is refused and reconnects the node's sockets every few
seconds until a handshake succeeds.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Sequence

import zmq
from zmq.utils.monitor import recv_monitor_message

__all__ = ["HANDSHAKE_EVENTS", "HandshakeWatch"]

log = logging.getLogger("palpa.net.transport")

_FAILURES: dict[int, str] = {zmq.EVENT_HANDSHAKE_FAILED_AUTH: "authentication refused",
                             zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL: "protocol error",
                             zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL: "handshake failed"}
HANDSHAKE_EVENTS = zmq.EVENT_HANDSHAKE_SUCCEEDED | sum(_FAILURES)
_RETRY_S = 2.0


class HandshakeWatch:
    """The monitor of a node's publisher socket (made with ``get_monitor_socket(HANDSHAKE_EVENTS)``) and what to
    reconnect when the bus refuses the node."""

    def __init__(self, monitor: zmq.Socket[bytes], owner: zmq.Socket[bytes], endpoint: str, curve: bool,
                 links: Sequence[tuple[zmq.Socket[bytes], str]], on_accepted: Callable[[], None]) -> None:
        self.monitor: zmq.Socket[bytes] | None = monitor
        self._owner = owner
        self._endpoint = endpoint
        self._curve = curve
        self._links = list(links)
        self._on_accepted = on_accepted
        self.refused = 0
        self._retry_at = 0.0

    def wait(self, timeout_s: float) -> bool:
        """Until the first handshake succeeds (True) or ``timeout_s`` passes; a refusal is logged on the way."""
        deadline = time.monotonic() + timeout_s
        while self.monitor is not None:
            remaining_ms = int((deadline - time.monotonic()) * 1000)
            if remaining_ms <= 0 or not self.monitor.poll(remaining_ms):
                return False
            if self._event():
                return True
        return True

    def check(self) -> bool:
        """Non-blocking: True once accepted (the monitor is then closed); reconnects while refused."""
        while self.monitor is not None and self.monitor.poll(0):
            if self._event():
                self._on_accepted()
                return True
        if self.monitor is not None and self.refused and time.monotonic() >= self._retry_at:
            self._retry_at = time.monotonic() + _RETRY_S
            for sock, endpoint in self._links:
                with contextlib.suppress(zmq.ZMQError):
                    sock.disconnect(endpoint)
                sock.connect(endpoint)
        return self.monitor is None

    def _event(self) -> bool:
        assert self.monitor is not None
        event = int(recv_monitor_message(self.monitor)["event"])
        if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
            if self.refused:
                log.warning("the bus at %s accepts this node now", self._endpoint)
            self.close()
            return True
        self.refused += 1
        self._retry_at = time.monotonic() + _RETRY_S
        if self.refused == 1:
            log.error("the bus at %s refused this node's handshake (%s): %s; retrying every %g s",
                      self._endpoint, _FAILURES.get(event, f"event {event}"),
                      "is its public key in the bus's --curve-clients folder (then SIGHUP the bus)?" if self._curve
                      else "is the bus CURVE-encrypted (PALPA_BUS_SERVER_KEY unset)?", _RETRY_S)
        return False

    def close(self) -> None:
        if self.monitor is not None:
            self._owner.disable_monitor()
            self.monitor.close(0)
            self.monitor = None
