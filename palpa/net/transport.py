"""Transports move envelopes between a node and the bus; the node never touches sockets itself.

:class:`ZmqTransport` talks to a real bus; :class:`palpa.net.memory.MemoryBus` provides an in-memory one so node
logic is tested without sockets. Both deliver ``Delivery`` items: the frames of one envelope
``[topic, header, payload, *blobs]`` and whether it came from the latched cache. The interface they share
(:class:`Transport`, :class:`Delivery`, :data:`SendFn`) is in :mod:`palpa.net.transport_api`, and re-exported here;
CURVE client keys from the environment in :mod:`palpa.net.keys`.
"""

from __future__ import annotations

import logging
import select
import time
from collections.abc import Callable, Sequence
from typing import cast

import zmq

from palpa.errors import BusError
from palpa.net.address import BusAddress, check_ipc_owner
from palpa.net.direct import (
    CLIENT_KEYS_TOPIC,
    DIRECTORY_PREFIX,
    DirectSocket,
    SubscriberSet,
    follow_directory,
)
from palpa.net.exitflush import note_linger
from palpa.net.handshake import HANDSHAKE_EVENTS, HandshakeWatch
from palpa.net.keys import curve_client_options
from palpa.net.options import TransportOptions
from palpa.net.reach import DirectReach
from palpa.net.transport_api import Delivery, SendFn, Transport

__all__ = ["Delivery", "SendFn", "Transport", "TransportOptions", "ZmqTransport", "curve_client_options"]

log = logging.getLogger("palpa.net.transport")

_SUBSCRIPTIONS_GRACE_MS = 100
_ZERO_COPY_BYTES = 65_536
_FD_SETSIZE = 1024
_RECONNECT_MAX_MS = 2000


# the backend's C methods, called without the pyzmq sugar layer's Python wrapper around every send and receive
_send = zmq.backend.Socket.send
_recv = zmq.backend.Socket.recv
_get = zmq.backend.Socket.get


def _send_frames(sock: zmq.Socket[bytes], frames: Sequence[bytes]) -> None:
    """``send_multipart`` without its per-call checks (a third of a small message's cost): large frames go
    without a copy, small ones are copied (cheaper than a zero-copy frame's bookkeeping)."""
    last = len(frames) - 1
    for i, frame in enumerate(frames):
        flags = zmq.SNDMORE if i < last else 0
        if len(frame) < _ZERO_COPY_BYTES:
            _send(sock, frame, flags)
        else:
            _send(sock, frame, flags, copy=False)


class ZmqTransport:
    """A PUB socket to the proxy, a SUB socket from it (and from direct publishers), a DEALER to the latched-value
    cache, and, once a topic is published direct, an XPUB its subscribers connect to (palpa.net.direct)."""

    def __init__(
        self,
        address: BusAddress,
        options: TransportOptions | None = None,
        *,
        context: zmq.Context[zmq.Socket[bytes]] | None = None,
        connect_timeout_s: float = 2.0,
    ) -> None:
        options = options or TransportOptions()
        self.options = options
        self._busy_poll_ns = options.busy_poll_us * 1000
        self._ctx = context or zmq.Context.instance()
        self._address = address
        curve = curve_client_options()
        self._curve = curve is not None
        self._bus_server_key = curve["server"] if curve is not None else None
        self._direct: DirectSocket | None = None
        self._peers: set[str] = set()
        self._bus_listeners = SubscriberSet()
        # an XPUB, not a PUB: it hears the proxy's subscriptions, so the constructor can wait until they have
        # arrived; a PUB would silently drop the first messages published while they are still on their way
        self._pub = self._ctx.socket(zmq.XPUB)
        self._sub = self._ctx.socket(zmq.SUB)
        self._latch = self._ctx.socket(zmq.DEALER)
        self._pub.sndhwm = options.sndhwm
        self._sub.rcvhwm = options.rcvhwm
        if options.max_msg_bytes:
            self._sub.maxmsgsize = self._latch.maxmsgsize = options.max_msg_bytes
        self._sub.reconnect_ivl_max = _RECONNECT_MAX_MS  # withdrawn direct publishers stay connected (cheaply)
        self.reach = DirectReach(self._sub)
        """Whether this node's subscriptions have reached its direct publishers (palpa.net.reach)."""
        for sock in (self._pub, self._sub, self._latch):
            if curve is not None:
                sock.curve_serverkey = curve["server"]
                sock.curve_publickey = curve["public"]
                sock.curve_secretkey = curve["secret"]
        for endpoint in (address.pub, address.sub, address.latch):
            check_ipc_owner(endpoint)
        monitor = self._pub.get_monitor_socket(HANDSHAKE_EVENTS)
        try:
            self._pub.connect(address.pub)
            self._sub.connect(address.sub)
            self._latch.connect(address.latch)
        except zmq.ZMQError as exc:
            self._pub.disable_monitor()
            monitor.close(0)
            self.close(0)
            raise BusError(f"cannot connect to bus {address}: {exc}") from None
        self._poller = zmq.Poller()
        self._socks: tuple[zmq.Socket[bytes], ...] = ()
        for sock in (self._sub, self._latch, self._pub):
            self._watch(sock)
        self._closed = False
        self._prefixes: list[bytes] = []
        self._unsent_latched: dict[bytes, list[bytes]] = {}
        self._directory_prefixes: list[bytes] = []
        self._directory_wants: dict[bytes, Callable[[str], bool]] = {}
        """Subscription prefix -> which topics under it are taken (``subscribe``'s ``wants``)."""
        self._watch_hs = HandshakeWatch(monitor, self._pub, address.pub, self._curve,
                                        [(self._pub, address.pub), (self._sub, address.sub),
                                         (self._latch, address.latch)], self._accepted)
        self.connected = self._await_proxy(self._watch_hs, connect_timeout_s)

    def _await_proxy(self, watch: HandshakeWatch, timeout_s: float) -> bool:
        """Wait (bounded) for the publisher's handshake with the proxy and for the proxy's first subscriptions,
        so the first message published is not lost; returns False when the bus did not answer in time (a
        refused node keeps the watch, which retries from :meth:`poll`)."""
        try:
            if not watch.wait(timeout_s):
                return False
            self._accepted()
            return True
        finally:
            if not watch.refused:
                watch.close()

    def _accepted(self) -> None:
        # the proxy forwards every current subscription on attach; none at all means nobody listens yet
        if self._pub.poll(_SUBSCRIPTIONS_GRACE_MS):
            self._drain_subscriptions(self._pub, self._bus_listeners)
        if self._watch_hs.refused:  # what the refused latch connection lost: ask again, set again
            for prefix in self._prefixes:
                self._to_cache([b"GET", prefix])
            for prefix in self._directory_prefixes:
                self._to_cache([b"GET", DIRECTORY_PREFIX + prefix])
            if self._direct is not None and self._curve:
                self._to_cache([b"GET", CLIENT_KEYS_TOPIC])
            unsent, self._unsent_latched = self._unsent_latched, {}
            for topic, frames in unsent.items():
                self._to_cache(frames, latched_topic=topic)
            self.connected = True

    def _watch(self, sock: zmq.Socket[bytes]) -> None:
        """Wait for input on ``sock`` too (in poll and in sub-ms waits)."""
        self._socks = (*self._socks, sock)
        self._fds = [cast(int, s.get(zmq.FD)) for s in self._socks]
        self._fds_selectable = max(self._fds) < _FD_SETSIZE
        self._poller.register(sock, zmq.POLLIN)

    def _drain_subscriptions(self, sock: zmq.Socket[bytes], listeners: SubscriberSet) -> None:
        while True:
            try:
                listeners.note(sock.recv(zmq.NOBLOCK))
            except zmq.Again:
                return

    def has_subscribers(self, topic: bytes) -> bool:
        direct = self._direct
        listeners = direct.listeners if direct is not None and direct.carries(topic) else self._bus_listeners
        return listeners.covers(topic)

    def sender(self, topic: bytes, direct: bool | None) -> SendFn:
        if direct is None:
            direct = topic.decode(errors="replace") in self.options.direct
        if not direct:
            return self.send
        if self._direct is None:
            opened = DirectSocket.bind(self._ctx, self._address, self.options.sndhwm, self._curve)
            if isinstance(opened, str):
                log.warning("%s goes through the bus, not direct: %s", topic.decode(errors="replace"), opened)
                return self.send
            self._direct = opened
            self._watch(opened.sock)
            if self._curve:  # whom to let in: the bus's own authorised keys (announcements wait for them)
                self._to_cache([b"GET", CLIENT_KEYS_TOPIC])
        self._direct.announce(self._to_cache, topic)
        return self._send_direct

    @property
    def direct_endpoint(self) -> str:
        """Where this node's direct topics leave from ("": none so far)."""
        return self._direct.endpoint if self._direct is not None else ""

    def sync_directory(self) -> bytes:
        """Ask the cache for a ``PONG`` after its answers to everything asked so far (``reach.synced(token)``)."""
        return self.reach.ping(self._to_cache)

    def _send_direct(self, frames: Sequence[bytes], latched: bool) -> None:
        assert self._direct is not None
        self._publish(self._direct.sock, frames, latched)

    def send(self, frames: Sequence[bytes], latched: bool) -> None:
        self._publish(self._pub, frames, latched)

    def _publish(self, sock: zmq.Socket[bytes], frames: Sequence[bytes], latched: bool) -> None:
        if len(frames) == 3 and len(frames[2]) < _ZERO_COPY_BYTES:  # the common case, unrolled
            _send(sock, frames[0], zmq.SNDMORE)
            _send(sock, frames[1], zmq.SNDMORE)
            _send(sock, frames[2], 0)
        else:
            _send_frames(sock, frames)
        if latched:
            self._to_cache([b"SET", *frames], latched_topic=frames[0])

    def _to_cache(self, frames: Sequence[bytes], latched_topic: bytes | None = None) -> None:
        """Send to the bus's last-value cache without ever blocking: a DEALER with no live connection (the
        bus refused this node's key, or it is not up yet) would block ``send`` for good. What cannot go now
        is kept (the newest value per latched topic) and sent when the bus accepts the node."""
        try:
            self._latch.send_multipart(list(frames), zmq.NOBLOCK)
        except zmq.Again:
            if latched_topic is not None:
                self._unsent_latched[latched_topic] = list(frames)

    def subscribe(self, prefix: bytes, request_latched: bool, wants: Callable[[str], bool] | None = None) -> None:
        self._sub.setsockopt(zmq.SUBSCRIBE, prefix)
        if wants is not None:
            self._directory_wants[prefix] = wants
        if request_latched:
            self._prefixes.append(prefix)
            self._to_cache([b"GET", prefix])  # asked again on acceptance when it cannot go now
        # direct publishers of matching topics, now and later (palpa.net.direct), on any bus; asked again on acceptance
        self._directory_prefixes.append(prefix)
        self._to_cache([b"GET", DIRECTORY_PREFIX + prefix])

    def unsubscribe(self, prefix: bytes) -> None:
        self._sub.setsockopt(zmq.UNSUBSCRIBE, prefix)

    def subscribe_probe(self, topic: bytes) -> None:
        """Subscribe to ``topic`` on the bus only (no latched value, no directory): a readiness probe."""
        self._sub.setsockopt(zmq.SUBSCRIBE, topic)

    def heard_subscription(self, prefix: bytes) -> bool:
        """Whether the proxy has forwarded a subscription to exactly ``prefix`` to this node's publisher socket.
        The proxy forwards subscriptions in the order its XPUB took them in, and it took in each subscriber's in
        the order they were made: when a node hears its own newest one, the proxy has all its earlier ones."""
        return prefix in self._bus_listeners.prefixes

    def subscribed_exactly(self, topic: bytes) -> bool:
        """Whether a subscription to exactly ``topic`` (not a shorter prefix: someone taking everything is not the
        one waited for) has reached the socket ``topic`` leaves from, direct or the bus's."""
        direct = self._direct
        return topic in (direct.listeners if direct is not None and direct.carries(topic) else
                         self._bus_listeners).prefixes

    def heard_join(self, node: str) -> bool:
        """Whether this node's publisher socket has heard ``node``'s readiness probe subscribed (palpa.node.presence), and
        so every subscription ``node`` made before it was ready: nothing published here now is lost to it."""
        return any(probe.rpartition("/")[0] == node for probe in self._bus_listeners.joined)

    @property
    def joins_heard(self) -> dict[str, None]:
        """Every readiness probe (``<node>/<pid>.<incarnation>``) this publisher socket has heard, in order (live:
        it grows)."""
        return self._bus_listeners.joined

    def poll(self, timeout_s: float, max_batch: int = 1000) -> list[Delivery]:
        out: list[Delivery] = []
        if self._watch_hs.monitor is not None:  # refused by the bus: retry (palpa.net.handshake)
            self._watch_hs.check()
        if timeout_s > 0:
            if self._busy_poll_ns:
                timeout_s = self._busy_wait(timeout_s)
                if timeout_s < 0:  # input arrived while spinning: take it now, the other sockets next call
                    self._read_sub(out, max_batch)
                    return out
            if 0 < timeout_s < 0.001:
                self._wait_fine(timeout_s)
                timeout_s = 0
        # whole ms, rounded down: the caller comes back for the rest (rounding up would make timers late and,
        # since each period starts from the last firing, drift; sub-ms waits go through _wait_fine)
        if timeout_s > 0:
            events = dict(self._poller.poll(int(timeout_s * 1000)))
        else:  # nothing to wait for: each socket's EVENTS (~1.6 us) is what zmq_poll would look at, without its cost
            events = {s: zmq.POLLIN for s in self._socks if cast(int, _get(s, zmq.EVENTS)) & zmq.POLLIN}
        if self._pub in events:
            self._drain_subscriptions(self._pub, self._bus_listeners)
        if self._direct is not None and self._direct.sock in events:
            self._direct.drain()
        if self._sub in events:
            self._read_sub(out, max_batch)
        if self._latch in events:
            while True:
                try:
                    frames = self._latch.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                if frames and frames[0] == b"VAL" and len(frames) >= 4:
                    if frames[1].startswith(DIRECTORY_PREFIX):
                        if self._takes_direct(frames[1]):
                            self._follow(frames[1], frames[3])
                    elif frames[1] == CLIENT_KEYS_TOPIC:
                        if self._direct is not None:
                            self._direct.allow(self._to_cache, frames[3])
                    else:
                        out.append(Delivery(frames[1:], True))
                elif len(frames) == 2 and frames[0] == b"PONG":
                    self.reach.pongs.add(frames[1])
                elif frames and frames[0] == b"ERR" and len(frames) >= 3:
                    log.warning("the bus's latch cache refused %r: %s", frames[1][:80],
                                frames[2][:300].decode(errors="replace"))
        return out

    def _follow(self, key: bytes, payload: bytes) -> None:
        """Connect to a direct publisher the cache told of, and probe it (palpa.net.reach)."""
        self.reach.told(key, payload)
        endpoint = follow_directory(self._sub, self._peers, key, payload, self._bus_server_key)
        if endpoint is not None:
            self.reach.connected(endpoint)

    def _takes_direct(self, key: bytes) -> bool:
        """Whether a subscription here takes the topic of a direct publisher's announcement (``key``): a recorder
        taking every topic but a lockstep's does not connect to the lockstep's direct sockets, whose ticks and
        acks (most of a simulation's messages) it would only drop."""
        topic = key[len(DIRECTORY_PREFIX):key.rfind(b"\0")]
        for prefix in self._directory_prefixes:
            if topic.startswith(prefix):
                wants = self._directory_wants.get(prefix)
                if wants is None or wants(topic.decode(errors="replace")):
                    return True
        return False

    def _read_sub(self, out: list[Delivery], max_batch: int) -> None:
        """Append up to ``max_batch`` envelopes waiting on the SUB socket (which has input).

        Frame.more, not recv_multipart: pyzmq's RCVMORE getsockopt costs ~2 us a frame, more than the receive
        itself; the rest of a multipart message is already here (ZeroMQ delivers it whole). After the first
        envelope, an EVENTS check (~1.6 us) decides whether to go on: ending on a failed receive costs ~5 us
        (pyzmq raises an exception), which a lone message, the low-latency case, would otherwise pay."""
        sub = self._sub
        for i in range(max_batch):
            if i == 1 and not cast(int, _get(sub, zmq.EVENTS)) & zmq.POLLIN:
                return
            try:
                frame = _recv(sub, zmq.NOBLOCK, False)
            except zmq.Again:
                return
            frames = [frame.bytes]
            while frame.more:
                frame = _recv(sub, 0, False)
                frames.append(frame.bytes)
            out.append(Delivery(frames, False))

    def _busy_wait(self, timeout_s: float) -> float:
        """Spin until the SUB socket has input or the busy-poll time is over; returns the time left to wait,
        or -1 when input arrived."""
        start = time.monotonic_ns()
        end = start + min(self._busy_poll_ns, int(timeout_s * 1e9))
        sub = self._sub
        while time.monotonic_ns() < end:
            if cast(int, _get(sub, zmq.EVENTS)) & zmq.POLLIN:
                return -1.0
        return max(0.0, timeout_s - (time.monotonic_ns() - start) / 1e9)

    def _wait_fine(self, timeout_s: float) -> None:
        """Wait less than a millisecond (ZeroMQ's poll counts whole ms) for input, sleeping in the kernel:
        select() on the sockets' notification descriptors. They are edge-like (they signal *changes*), so
        pending input is checked first; a wake-up without input is harmless (the caller polls again)."""
        for sock in self._socks:
            if cast(int, _get(sock, zmq.EVENTS)) & zmq.POLLIN:
                return
        if self._fds_selectable:
            select.select(self._fds, [], [], timeout_s)
        else:  # select() cannot take descriptors past FD_SETSIZE; input then waits this (< 1 ms) sleep out
            time.sleep(timeout_s)

    def close(self, linger_ms: int) -> None:
        if getattr(self, "_closed", False):
            return
        self._closed = True
        if hasattr(self, "_watch_hs"):
            self._watch_hs.close()
        if self._direct is not None:  # withdraws its announcements first (through the latch socket)
            self._direct.close(self._to_cache, linger_ms)
        for sock in (self._pub, self._sub, self._latch):
            sock.close(linger_ms)
        note_linger(self._ctx, linger_ms)
