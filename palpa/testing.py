"""Test helpers shipped with the runtime: an in-memory bus and a harness that drives one node on a mock clock.

    h = NodeHarness(MyNode, params={"gain": 2.0})
    h.publish("probe/heights", ProbeHeights(...))
    h.advance(0.5)                      # fires the node's timers due in the next half second
    assert h.published("stiffness/sample")[-1].valid

No sockets, no processes, no sleeps: everything runs in the calling thread, in milliseconds.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Generic, TypeVar

import msgspec

from palpa.message import Message, lookup
from palpa.net.transport import Delivery, SendFn
from palpa.node.node import Node, Publisher, RawMessage
from palpa.node.params import Params
from palpa.timing.clock import MockClock

__all__ = ["GraphHarness", "MemoryBus", "MemoryTransport", "NodeHarness"]

N = TypeVar("N", bound=Node)
M = TypeVar("M", bound=Message)


class MemoryBus:
    """Routes envelopes between in-process transports with ZeroMQ's prefix semantics and a latched cache."""

    def __init__(self) -> None:
        self._transports: list[MemoryTransport] = []
        self._cache: dict[bytes, list[bytes]] = {}
        self._listeners: dict[bytes, list[MemoryTransport]] = {}
        self.pump: Callable[[], None] | None = None
        """Lets the other nodes run while one waits on a service call (set by :class:`GraphHarness`)."""

    def transport(self) -> MemoryTransport:
        t = MemoryTransport(self)
        self._add(t)
        return t

    def _add(self, t: MemoryTransport) -> None:
        self._transports.append(t)
        self.changed()

    def changed(self) -> None:
        """Forget who listens to what (a transport subscribed, unsubscribed or closed)."""
        self._listeners.clear()

    def _route(self, frames: list[bytes], latched: bool) -> None:
        if latched:
            self._cache[frames[0]] = frames[1:]
        for t in self.listeners(frames[0]):
            t.inbox.append(Delivery(list(frames), False))

    def listeners(self, topic: bytes) -> list[MemoryTransport]:
        """The open transports with a subscription matching ``topic`` (ZeroMQ's prefix rule)."""
        found = self._listeners.get(topic)
        if found is None:
            found = self._listeners[topic] = [t for t in self._transports
                                              if not t.closed and any(topic.startswith(p) for p in t.prefixes)]
        return found

    def pending(self) -> bool:
        return any(t.inbox for t in self._transports if not t.closed)


class MemoryTransport:
    """One node's connection to a :class:`MemoryBus`."""

    def __init__(self, bus: MemoryBus) -> None:
        self.bus = bus
        self.prefixes: list[bytes] = []
        self.inbox: deque[Delivery] = deque()
        self.closed = False

    def send(self, frames: Sequence[bytes], latched: bool) -> None:
        self.bus._route([bytes(f) for f in frames], latched)

    def sender(self, topic: bytes, direct: bool | None) -> SendFn:
        return self.send  # in memory every topic is direct

    def has_subscribers(self, topic: bytes) -> bool:
        return bool(self.bus.listeners(topic))

    def subscribe(self, prefix: bytes, request_latched: bool, wants: Callable[[str], bool] | None = None) -> None:
        self.prefixes.append(prefix)
        self.bus.changed()
        if request_latched:
            for topic, rest in self.bus._cache.items():
                if topic.startswith(prefix):
                    self.inbox.append(Delivery([topic, *rest], True))

    def unsubscribe(self, prefix: bytes) -> None:
        if prefix in self.prefixes:
            self.prefixes.remove(prefix)
            self.bus.changed()

    def pump(self) -> None:
        """Run the rest of the graph once (a node blocked in a service call waits for the others this way)."""
        if self.bus.pump is not None:
            self.bus.pump()

    def poll(self, timeout_s: float) -> list[Delivery]:
        out = list(self.inbox)
        self.inbox.clear()
        return out

    def close(self, linger_ms: int) -> None:
        self.closed = True
        self.bus.changed()


class GraphHarness:
    """Several nodes on one :class:`MemoryBus` and one :class:`MockClock`: a whole (sub)graph in one thread.

        g = GraphHarness([(StaticPose, {}), (PressureController, {"startup": "hold", "setpoint_kpa": 40})])
        g.advance(2.0)
        g.published("pressure/state")

    Everything published is recorded (``raw``, ``published(topic)``); ``advance`` stops at every timer deadline
    of every node, so no tick is skipped.
    """

    def __init__(self, nodes: Sequence[tuple[type[Node], Mapping[str, Any] | None]] = (),
                 clock: MockClock | None = None, bus: MemoryBus | None = None) -> None:
        self.bus = bus or MemoryBus()
        self.clock = clock or MockClock()
        self.bus.pump = self._pump
        self._probe = Node(name="harness", transport=self.bus.transport(), clock=self.clock, heartbeat_s=0)
        self.raw: list[RawMessage] = []
        self._probe.subscribe_raw("", self.raw.append)
        self._pubs: dict[str, Publisher[Any]] = {}
        self.nodes: list[Node] = []
        for cls, params in nodes:
            self.add(cls, params)

    def add(self, cls: type[N], params: Mapping[str, Any] | Params | None = None, **kwargs: Any) -> N:
        """Start a node of ``cls`` on the harness's bus and clock (no heartbeats unless asked)."""
        kwargs.setdefault("heartbeat_s", 0)
        node = cls(params=params, transport=self.bus.transport(), clock=self.clock, **kwargs)
        self.nodes.append(node)
        self.spin()
        return node

    def spin(self, max_rounds: int = 10_000) -> None:
        """Deliver everything in flight between the nodes until the bus is quiet."""
        for _ in range(max_rounds):
            for node in self.nodes:
                node.spin_once(0)
            self._probe.spin_once(0)
            if not self.bus.pending():
                return
        raise RuntimeError("the bus did not go quiet: a publish loop between callbacks?")

    def _pump(self) -> None:
        for node in self.nodes:
            node.spin_once(0)
        self._probe.spin_once(0)

    def publish(self, topic: str, msg: Message, *, stamp_ns: int | None = None, latched: bool = False,
                blobs: Sequence[bytes] = ()) -> None:
        """Send ``msg`` on ``topic`` as another node would, and let the nodes handle it."""
        pub = self._pubs.get(topic)
        if pub is None:
            pub = self._pubs[topic] = self._probe.publisher(topic, type(msg), latched=latched)
        pub.publish(msg, stamp_ns=stamp_ns, blobs=blobs)
        self.spin()

    def publish_raw(self, frames: Sequence[bytes]) -> None:
        """Send arbitrary frames (malformed ones included) and let the nodes handle them."""
        self.bus._route([bytes(f) for f in frames], False)
        self.spin()

    def advance(self, seconds: float) -> None:
        """Move time forward, stopping at every timer deadline of every node."""
        end = self.clock.now_ns() + int(round(seconds * 1e9))
        while True:
            dues = [d for n in self.nodes if (d := n.next_timer_due_ns()) is not None]
            due = min(dues) if dues else None
            if due is None or due > end:
                break
            self.clock.set(max(due, self.clock.now_ns()))
            self.spin()
        self.clock.set(end)
        self.spin()

    def published(self, topic: str, msg_type: type[M] | None = None) -> list[Any]:
        """Every message the nodes published on ``topic`` so far, decoded (by the header's type name)."""
        out = []
        for raw in self.raw:
            if raw.topic == topic and raw.header.node != "harness":
                out.append(msgspec.msgpack.decode(raw.payload, type=msg_type or lookup(raw.header.type)))
        return out

    def clear(self) -> None:
        """Forget what was recorded so far (long simulations)."""
        self.raw.clear()

    def close(self) -> None:
        for node in self.nodes:
            node.close(0)
        self._probe.close(0)

    def __enter__(self) -> GraphHarness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class NodeHarness(GraphHarness, Generic[N]):
    """Runs one node (``.node``) on a :class:`MemoryBus` and a :class:`MockClock`, feeding it input and recording
    its output: a :class:`GraphHarness` of one."""

    def __init__(
        self,
        node_cls: type[N],
        params: Mapping[str, Any] | Params | None = None,
        *,
        name: str | None = None,
        clock: MockClock | None = None,
        bus: MemoryBus | None = None,
        **node_kwargs: Any,
    ) -> None:
        super().__init__(clock=clock, bus=bus)
        self.node: N = self.add(node_cls, params, name=name, **node_kwargs)
