"""Messages the runtime itself publishes: heartbeats (``_palpa/heartbeat``) and logs (``_palpa/log``)."""

from __future__ import annotations

import msgspec

from palpa.message import Message

__all__ = ["CLOCK_ACK_TOPIC", "CLOCK_TOPIC", "HEARTBEAT_TOPIC", "LOG_TOPIC", "TICK_PREFIX", "ClockAck", "ClockTick",
           "Heartbeat", "LogRecord", "TopicCounters", "tick_topic"]

HEARTBEAT_TOPIC = "_palpa/heartbeat"
LOG_TOPIC = "_palpa/log"
CLOCK_TOPIC = "_palpa/clock"
CLOCK_ACK_TOPIC = "_palpa/lockstep"
"""Not under ``_palpa/clock``: ZeroMQ matches by prefix, and every sim-clock node would wake for every ack."""
TICK_PREFIX = "_palpa/tick/"


def tick_topic(node: str) -> str:
    """Where the event lockstep's clock sends ``node`` alone the instants of its timers' deadlines (the trailing
    ``/``: ZeroMQ matches by prefix, and node ``map`` must not hear ``map2``'s)."""
    return f"{TICK_PREFIX}{node}/"


class TopicCounters(msgspec.Struct, frozen=True, kw_only=True):
    """Receive counters of one subscribed topic (see palpa.net.wire.TopicStats)."""

    received: int = 0
    gaps: int = 0
    duplicates: int = 0
    restarts: int = 0
    decode_errors: int = 0


class Heartbeat(Message, frozen=True, kw_only=True):
    """Published by every node once a second so tools can list the graph (``palpa node list``)."""

    node: str
    pid: int
    host: str
    publishes: dict[str, str]
    """Topic -> message type name."""
    subscribes: dict[str, str]
    """Topic -> message type name ('*' for raw/prefix subscriptions)."""
    counters: dict[str, TopicCounters]
    sent: dict[str, int]
    """Topic -> the ``seq`` of the last message published on it (this heartbeat's own included)."""
    uptime_s: float
    state: str = "running"
    """``running``; ``leaving`` in the last heartbeat a node sends, as it closes."""
    direct: list[str] = []
    """Published topics sent straight to their subscribers, past the proxy (palpa.net.direct)."""
    services: dict[str, str] = {}
    """Service name -> 'Request -> Response' (palpa.node.service)."""
    wire: int = 1
    """The wire protocol version the node speaks (palpa.net.wire.WIRE_VERSION; absent: 1, a node from before it)."""
    refused: dict[str, int] = {}
    """Inputs the node refused and counted, by kind (``clock_ack/not_sender``...; bad messages are in ``counters``)."""


class LogRecord(Message, frozen=True, kw_only=True):
    """One log line of a node. ``level`` is a Python logging level name (DEBUG, INFO, WARNING, ERROR)."""

    node: str
    level: str
    text: str
    stamp_ns: int


class ClockTick(Message, frozen=True, kw_only=True):
    """Simulation / replay time (topic ``_palpa/clock``), published by the launch's clock and ``palpa play --clock``.

    ``hold``: time exists but does not run yet: a node sets up (its timers count from ``sim_ns``) but runs no timer
    until a tick without ``hold`` (the lockstep clock holds the start until every launched node has joined).
    ``lead``: the clock keeps time within a lead of the nodes' acks (not the event lockstep): ack every few ms."""

    sim_ns: int
    hold: bool = False
    lead: bool = False


class ClockAck(Message, frozen=True, kw_only=True):
    """A sim-clock node's report that it has handled everything up to ``sim_ns`` (topic ``_palpa/lockstep``).

    With ``next_ns`` (>= 0) the report is an event-lockstep one (palpa.timing.simclock): the node has run its timers due
    at ``sim_ns`` and handled every message it counted in ``recv``; its next timer is due at ``next_ns`` (0: none).
    ``sent``/``recv`` count the messages it published / took in per topic since it started (runtime ``_palpa/``
    topics excepted), ``subs`` names what it subscribes to (a prefix ends in ``*``): the clock moves on only when
    every message sent at this time has been taken in by every subscriber. Without ``next_ns`` (-1, an older or
    hand-written client) the clock only stays within a small lead of ``sim_ns``. ``leaving``: the node's last ack,
    sent as it closes: it no longer holds simulated time back. ``probe``: the readiness probe that confirmed the
    node's subscriptions through the bus (``<node>/<pid>.<incarnation>``, palpa.node.presence; empty on a bus without
    one); the other participants must say they have ``heard`` it (``heard``: the probes this node's publisher socket
    heard since its previous ack) before the clock counts on them to reach it. ``direct``/``direct_at``: the topics it
    publishes straight to their subscribers (palpa.net.direct) and the endpoint they leave from; ``reached``: the
    direct endpoints that answered this node's direct probes since its previous ack (palpa.net.reach): the clock
    counts on a subscriber of a direct topic only once it has reached every participant publishing it. ``mac``: its
    signature (palpa.timing.acksign): a launched node's acks are believed only with it."""

    node: str
    sim_ns: int
    leaving: bool = False
    next_ns: int = -1
    sent: dict[str, int] = {}
    recv: dict[str, int] = {}
    subs: list[str] = []
    probe: str = ""
    heard: list[str] = []
    direct: list[str] = []
    direct_at: str = ""
    reached: list[str] = []
    mac: bytes = b""
    """The node's signature of this ack (palpa.timing.acksign) when its launcher gave it a key; empty otherwise."""
