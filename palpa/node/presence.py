"""What a node tells the bus about itself besides its data: that it is ready (its subscriptions confirmed end to
end), that it is alive (heartbeats on ``_palpa/heartbeat``), and what it logs (``_palpa/log``).

:class:`palpa.node.node.Node` uses these once it is set up; they are apart from it because none of them is part of
the node's own traffic: they are how launchers, ``palpa node list`` and the lockstep clock learn about a node.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Mapping
from typing import Any

from palpa.net.direct import JOIN_PROBE_PREFIX, REACH_PREFIX
from palpa.net.transport import ZmqTransport
from palpa.net.wire import WIRE_VERSION, Header, encode_header
from palpa.node.endpoints import Publisher, RawMessage
from palpa.node.nodeapi import NodeApi
from palpa.node.receive import Receiver
from palpa.node.service import Service
from palpa.runtime_msgs import HEARTBEAT_TOPIC, LOG_TOPIC, Heartbeat, LogRecord, TopicCounters

__all__ = ["JOIN_TIMEOUT_S", "LOG_TEXT_MAX", "BusLogHandler", "Heartbeats", "confirm_subscriptions", "take_reach_answers"]

JOIN_TIMEOUT_S = 10.0
"""Wall seconds a node waits for the bus to confirm its subscriptions before it counts as ready anyway (warning)."""
_PROBE_REPEAT_NS = 50_000_000
"""Wall ns after which an unanswered readiness probe is sent again (a catch-all subscriber let the first one go
out before the proxy had our own probe subscription)."""
LOG_TEXT_MAX = 4000
"""Characters of a log line published on ``_palpa/log``; the rest is cut (a peer's bytes can end up in a line)."""


def confirm_subscriptions(node: NodeApi, rx: Receiver, incarnation: int, timeout_s: float) -> str:
    """Wait until the subscriptions ``node`` made so far are live end to end, so that a node counts as ready
    (heartbeats, its first lockstep ack) only once nothing published to it can be dropped for lack of a route;
    returns the readiness probe the bus echoed (``<name>/<pid>.<incarnation>``; "" when none was: see below).

    ZeroMQ subscriptions travel asynchronously (SUB -> the proxy's XPUB -> its XSUB -> every publisher's XPUB),
    and a message published before its subscription has arrived is dropped without a trace; under load that
    took a lockstep run's first message on a topic (the clock then waited for it, 30 s). So: subscribe a
    private probe topic last, wait until the proxy forwards it back to our own publisher socket (it forwards in
    order: every earlier subscription of ours is then in the proxy's filter), and publish the probe until it
    comes back through the bus. Every other publisher hears the probe subscription after all our earlier ones
    too (one connection from the proxy delivers in order), so one that has heard it (``heard_join``) reaches
    us: the lockstep clock waits for that (ClockAck ``probe``/``heard``), as the player does for ``wait_for``.

    Topics published direct (palpa.net.direct) do not pass the proxy: then wait as well until the cache has answered
    every directory request (``PING``/``PONG``) and every direct publisher it named has answered this node's
    direct probe (palpa.net.reach): each of them has our subscriptions. Publishers announced after that are probed
    when they appear; the lockstep clock waits for those answers (palpa.timing.lockstep), nothing on the wall clock does
    (docs/wire.md, *Direct topics*). Only on a real bus (in memory,
    subscriptions are immediate) and while it is connected."""
    t = node.transport
    if not isinstance(t, ZmqTransport) or not t.connected or timeout_s <= 0 or not (rx.subs or rx.raw):
        return ""
    key = JOIN_PROBE_PREFIX + f"{node.name}/{os.getpid()}.{incarnation:x}".encode()
    echoed: list[RawMessage] = []
    rx.add_raw(key, echoed.append)
    t.subscribe_probe(key)
    header = encode_header(Header(type="", seq=0, stamp=node.clock.now_ns(), node=node.name))
    start = time.monotonic_ns()
    deadline, sent = start + int(timeout_s * 1e9), 0
    try:
        while not echoed and not node.is_shutdown:
            now = time.monotonic_ns()
            if now > deadline:
                node.log.warning("the bus did not confirm this node's subscriptions within %.0f s (wall "
                                 "clock): the first messages published to it may be lost", timeout_s)
                return ""
            if now - sent > _PROBE_REPEAT_NS and t.heard_subscription(key):
                sent = now
                t.send([key, header, b"\xc0"], False)
            node.spin_once(0.005)
        rx.remove_raw(key)
        t.unsubscribe(key)
        token = t.sync_directory()
        while not (t.reach.synced(token) and not t.reach.pending()) and not node.is_shutdown:
            if time.monotonic_ns() > deadline:
                node.log.warning("direct publisher(s) %s did not confirm this node's subscriptions within %.0f s "
                                 "(wall clock): the first messages they publish to it may be lost",
                                 ", ".join(t.reach.pending()) or "(the bus's directory did not answer)", timeout_s)
                break
            node.spin_once(0.005)
        return key[len(JOIN_PROBE_PREFIX):].decode()
    finally:
        rx.remove_raw(key)
        t.unsubscribe(key)


def take_reach_answers(node: NodeApi, rx: Receiver) -> None:
    """Hand the direct publishers' answers to this node's direct probes to its transport (palpa.net.reach), from
    before setup on: a connection made while setting up is probed too."""
    t = node.transport
    if isinstance(t, ZmqTransport):
        reach = t.reach
        rx.add_raw(reach.prefix, lambda raw: reach.answered(raw.topic.encode(), raw.payload.decode(errors="replace")))


class Heartbeats:
    """A node's heartbeats on ``_palpa/heartbeat``: what it publishes, subscribes, serves and has counted, every
    ``period_s`` on the wall clock whatever the node's clock (a listener waits a wall-clock window, and a node waiting for simulated time,
    or a paused replay, is still alive). ``pubs``, ``rx`` and ``services`` are the node's own."""

    def __init__(self, node: NodeApi, period_s: float, rx: Receiver, pubs: Mapping[str, Publisher[Any]],
                 services: Mapping[str, Service[Any, Any]]) -> None:
        self._node = node
        self._pub = node.publisher(HEARTBEAT_TOPIC, Heartbeat)
        self._rx = rx
        self._pubs = pubs
        self._services = services
        self._started_ns = time.monotonic_ns()
        self._period_ns = int(period_s * 1e9) if period_s > 0 else 0
        self._due_ns = time.monotonic_ns()

    def beat(self) -> None:
        """Send the heartbeat when it is due on the wall clock (through the node's dispatch)."""
        if not self._period_ns or self._node.is_shutdown:
            return
        now = time.monotonic_ns()
        if now >= self._due_ns:
            self._due_ns = now + self._period_ns
            self._node.dispatch.call(self.send)

    def wait_s(self, timeout_s: float) -> float:
        """``timeout_s`` cut to the time left until the next heartbeat is due."""
        if not self._period_ns:
            return timeout_s
        return max(0.0, min(timeout_s, (self._due_ns - time.monotonic_ns()) / 1e9))

    def leave(self) -> None:
        """Send the last heartbeat, ``state: leaving``, as the node closes (tools stop listing it at once)."""
        if self._period_ns:
            self.send("leaving")

    def send(self, state: str = "running") -> None:
        """Send the heartbeat now."""
        rx, pubs = self._rx, self._pubs
        subs = {s.topic: s.type.type_name for s in rx.subs.values()}
        subs.update({r.prefix.decode() + "*": "*" for r in rx.raw if not r.prefix.startswith(REACH_PREFIX)})
        sent = {p.topic: p.seq for p in pubs.values()}
        sent[HEARTBEAT_TOPIC] = self._pub.seq + 1  # this heartbeat counts itself: its own seq
        self._pub.publish(
            Heartbeat(
                node=self._node.name,
                pid=os.getpid(),
                host=socket.gethostname(),
                publishes={p.topic: p.type.type_name for p in pubs.values()},
                subscribes=subs,
                counters={t: TopicCounters(**s.as_dict()) for t, s in rx.counters().items()},
                sent=sent,
                uptime_s=(time.monotonic_ns() - self._started_ns) / 1e9,
                state=state,
                wire=WIRE_VERSION,
                direct=[p.topic for p in pubs.values() if p.direct],
                services={name: srv.types for name, srv in self._services.items()},
                refused=dict(self._node.refusals),
            )
        )


def _truncate(text: str) -> str:
    return text if len(text) <= LOG_TEXT_MAX else f"{text[:LOG_TEXT_MAX]}... ({len(text) - LOG_TEXT_MAX} more chars)"


class BusLogHandler(logging.Handler):
    """Publishes a node's log records (INFO and up) on ``_palpa/log``, cut to :data:`LOG_TEXT_MAX` characters;
    never raises, and never publishes from inside its own publishing or once the node is closed."""

    def __init__(self, node: NodeApi) -> None:
        super().__init__(logging.INFO)
        self._node = node
        self._pub = node.publisher(LOG_TOPIC, LogRecord)
        self._busy = False

    def emit(self, record: logging.LogRecord) -> None:
        if self._busy or self._node.closed:
            return
        self._busy = True
        try:
            self._pub.publish(
                LogRecord(node=self._node.name, level=record.levelname, text=_truncate(record.getMessage()),
                          stamp_ns=self._node.clock.now_ns())
            )
        except Exception:  # a log line must never take the node down
            pass
        finally:
            self._busy = False
