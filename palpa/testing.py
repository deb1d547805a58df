"""Test helpers shipped with the runtime: harnesses that drive nodes on the in-memory bus (:mod:`palpa.net.memory`,
whose classes are re-exported here) and a mock clock.

    h = NodeHarness(MyNode, params={"gain": 2.0})
    h.publish("probe/heights", ProbeHeights(...))
    h.advance(0.5)                      # fires the node's timers due in the next half second
    assert h.published("stiffness/sample")[-1].valid

No sockets, no processes, no sleeps: everything runs in the calling thread, in milliseconds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Generic, TypeVar

import msgspec

from palpa.message import Message, lookup
from palpa.net.memory import MemoryBus, MemoryTransport
from palpa.node.node import Node, Publisher, RawMessage
from palpa.node.params import Params
from palpa.timing.clock import MockClock

__all__ = ["GraphHarness", "MemoryBus", "MemoryTransport", "NodeHarness"]

N = TypeVar("N", bound=Node)
M = TypeVar("M", bound=Message)


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
        self.bus.route(frames)
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
