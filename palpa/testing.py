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
from pathlib import Path
from typing import Any, Generic, TypeVar

import msgspec

from palpa.message import Message, lookup
from palpa.net.memory import MemoryBus, MemoryTransport
from palpa.node.node import Node, Publisher, RawMessage
from palpa.node.params import Params
from palpa.timing.clock import MockClock
from palpa.timing.compose import Composition

__all__ = ["GraphHarness", "MemoryBus", "MemoryTransport", "NodeHarness"]

N = TypeVar("N", bound=Node)
M = TypeVar("M", bound=Message)


class GraphHarness:
    """Several nodes on one :class:`MemoryBus` and one :class:`MockClock`: a whole (sub)graph in one thread.

        g = GraphHarness([(StaticPose, {}), (PressureController, {"startup": "hold", "setpoint_kpa": 40})])
        g.advance(2.0)
        g.published("pressure/state")

    A thin facade over :class:`~palpa.timing.compose.Composition` (``.composition``), the executor of
    ``palpa launch --in-process``: ``advance`` moves its clock from timer deadline to timer deadline, and at each
    instant every due timer runs before any message sent at that instant is handled, so a test runs the timeline
    the composed graph runs. Everything published is recorded (``raw``, ``published(topic)``).
    """

    def __init__(self, nodes: Sequence[tuple[type[Node], Mapping[str, Any] | None]] = (),
                 clock: MockClock | None = None, bus: MemoryBus | None = None) -> None:
        self.clock = clock or MockClock()
        self.composition = Composition(clock=self.clock, heartbeat_s=0, bus=bus)
        self.bus = self.composition.bus
        self._probe = Node(name="harness", transport=self.bus.transport(), clock=self.clock, heartbeat_s=0)
        self.raw: list[RawMessage] = []
        self._probe.subscribe_raw("", self.raw.append)
        self._pubs: dict[str, Publisher[Any]] = {}
        self.composition.adopt(self._probe)
        for cls, params in nodes:
            self.add(cls, params)

    @classmethod
    def from_launch(cls, file: str | Path, *, run_dir: str | Path | None = None, clock: MockClock | None = None,
                    node_params: Mapping[str, Mapping[str, Any]] | None = None, every_node: bool = False,
                    **args: Any) -> GraphHarness:
        """The simulated-clock nodes of a launch file, composed on the mock clock in this process as
        ``palpa launch FILE --in-process`` composes them (same classes, names, parameters, namespaces, remaps and
        order; no process, no socket). ``args`` override the file's args (native values, as ``name:=value`` would
        give). Not run here: the file's ``prepare`` commands (processes: pass args naming their outputs instead),
        its recorder (the harness records everything itself, in ``raw``), its clock source (the harness's clock
        replaces it) and its entries off the simulated clock. ``node_params`` overrides parameters the file fixes,
        by node name (``{"map": {"png_helper": False}}``: no helper process). ``every_node``
        composes the file's wall-clock node entries too, on the harness's clock (a rig's graph whose drivers have
        in-process stand-ins, such as launch/scan_ur.yaml on the emulated UR controller of emulators.ur.local). A
        :class:`~palpa.errors.LaunchError` says what is wrong with the file, the args or ``node_params``."""
        from palpa.errors import LaunchError
        from palpa.launch.compose import CLOCK_TARGET, composable_nodes
        from palpa.launch.loader import load_launch
        from palpa.launch.plan import NodeSpec
        from palpa.targets import load_node_class

        plan = load_launch(file, args, run_dir=run_dir)
        specs: list[NodeSpec] = [s for s in plan.nodes if s.target not in (None, CLOCK_TARGET)] if every_node else \
            composable_nodes(plan)
        extra = dict(node_params or {})
        if unknown := sorted(set(extra) - {s.name for s in specs}):
            raise LaunchError(f"{file}: node_params for {', '.join(unknown)}: no such {'' if every_node else 'simulated-clock '}node "
                              f"(there are {', '.join(s.name for s in specs)})")
        classes = [load_node_class(s.target) for s in specs if s.target is not None]
        g = cls(clock=clock)
        try:
            for spec, node_cls in zip(specs, classes, strict=True):
                g.add(node_cls, {**spec.params, **extra.get(spec.name, {})}, name=spec.name, namespace=spec.namespace,
                      remap=spec.remap)
        except BaseException:
            g.close()
            raise
        return g

    @property
    def nodes(self) -> list[Node]:
        """The nodes under test, in the order they were added (not the harness's own probe; not those that ended)."""
        return [n for n in self.composition.nodes if n is not self._probe]

    def add(self, cls: type[N], params: Mapping[str, Any] | Params | None = None, **kwargs: Any) -> N:
        """Start a node of ``cls`` on the harness's bus and clock (no heartbeats unless asked): its ``setup`` runs
        now and what it published is handled, as :meth:`Composition.adopt` does; its timers run from the next
        :meth:`advance` or :meth:`spin`."""
        kwargs.setdefault("heartbeat_s", 0)
        node = cls(params=params, transport=self.bus.transport(), clock=self.clock, **kwargs)
        self.composition.adopt(node)
        return node

    def spin(self) -> None:
        """Run the timers due now, then deliver everything in flight between the nodes until the bus is quiet
        (the composition's step at the current instant; time does not move)."""
        now = self.clock.now_ns()
        while self.composition.step(now):
            pass
        self.composition.settle()

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
        """Move time forward by ``seconds``, stopping at every timer deadline of every node (the composition's
        steps), then let the nodes handle what is in flight at the end."""
        end = self.clock.now_ns() + int(round(seconds * 1e9))
        while self.composition.step(end):
            pass
        self.clock.set(max(end, self.clock.now_ns()))
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
        """Close every node as the composition does (``on_shutdown`` first, each after the others handled what it
        published while closing)."""
        self.composition.close()

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
