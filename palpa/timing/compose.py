"""Composition: several nodes in one process on one simulated clock that jumps from event to event.

A multi-process simulation pays for every message twice (a send, a receive through the proxy) and for the lockstep
clock (ticks out, acknowledgements back); the graph then runs as fast as the slowest exchange allows. Composed,
the same node classes share an in-memory bus and a :class:`~palpa.timing.clock.MockClock` that :class:`Composition`
moves straight to the next timer deadline of any node once every message in flight has been handled: time goes
as fast as the CPU computes the nodes' work, and a run is deterministic (the same seed gives the same output).

The composed graph still lives on the real bus, through one bridge connection: everything its nodes publish
(heartbeats and log lines included) goes out, so ``palpa topic echo/hz``, ``palpa node list``, a recorder or the
launcher's progress bar outside see it as they would see separate processes; what outside publishers send on a
topic the composed nodes subscribe to (and do not publish themselves) comes in.

``palpa launch FILE --in-process`` (or ``in_process: true`` in the file) runs a launch file's simulated-clock
nodes, its clock and its recorder this way, as one child process: ``python -m palpa.timing.compose GRAPH.json``.
"""

from __future__ import annotations

import gc
import logging
import signal
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

import msgspec

from palpa.errors import DecodeError, PalpaError
from palpa.exiting import exit_now
from palpa.net.address import from_env
from palpa.net.memory import MemoryBus, MemoryTransport
from palpa.net.transport import Delivery, Transport, TransportOptions, ZmqTransport
from palpa.net.wire import parse_envelope
from palpa.node.node import Node
from palpa.startgate import wait_for_go
from palpa.timing.clock import MockClock
from palpa.timing.hub import HubBus

__all__ = ["Composition", "ComposedNode", "GraphSpec", "main"]

log = logging.getLogger("palpa.timing.compose")

_IDLE_WAIT_S = 0.05
_MAX_ROUNDS = 100_000
_OUTSIDE_POLL_NS = 2_000_000
"""Wall ns between looks at the bridge for input from outside while the composition is busy (an idle one waits on
the bridge)."""


@dataclass
class ComposedNode:
    """One node of a composition as a launch file describes it (``python -m palpa.timing.compose`` builds it)."""

    name: str
    target: str
    """``package.module:Class``."""
    params: dict[str, Any] = field(default_factory=dict)
    namespace: str = ""
    remap: dict[str, str] = field(default_factory=dict)
    required: bool = False
    """Its end ends the composition (with its exit code), as a launch file's ``required``."""


class GraphSpec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """What ``python -m palpa.timing.compose`` runs (written by the launcher as JSON)."""

    nodes: list[dict[str, Any]]
    """Each a :class:`ComposedNode`'s fields."""
    heartbeat_s: float = 1.0


class Composition:
    """Nodes sharing one in-memory bus and one simulated clock; :meth:`run` advances time event by event.

    ``bridge`` connects the composition to a real bus (None: a closed world, as in tests). Nodes are added with
    :meth:`add` (a class and its parameters, as a launch file gives them) or :meth:`adopt` (a node built by the
    caller on :meth:`transport` and :attr:`clock`).
    """

    def __init__(self, *, bridge: Transport | None = None, clock: MockClock | None = None,
                 heartbeat_s: float = 1.0, bus: MemoryBus | None = None) -> None:
        # on a whole second: time grids of the sim drivers (multiples of their periods) then fall at the same
        # offsets from the start in every run, and the same seed gives the same output
        self.clock = clock or MockClock(time.time_ns() // 1_000_000_000 * 1_000_000_000)
        if bus is not None and bridge is not None:
            raise ValueError("a composition with a bridge runs on its own bus (bus= is for a closed world)")
        self._hub: HubBus | None = None
        self.bus: MemoryBus
        if bus is None:
            self.bus = self._hub = HubBus(bridge)
        else:
            self.bus = bus
        self.bridge = bridge
        self.heartbeat_s = heartbeat_s
        self.nodes: list[Node] = []
        self.required: set[str] = set()
        self.exit_code = 0
        self.ended: list[tuple[str, int]] = []
        """(node name, exit code) of every node that ended by itself, in order."""
        self._names: set[str] = set()
        """The composed nodes' names: what comes back from the proxy under one of them (or a client id of one) is
        an echo of our own."""
        self._stop = False
        self._inbox_list: list[tuple[Node, MemoryTransport]] | None = None
        self._outside_polled_ns = 0
        self.bus.pump = self._pump

    # -- building --------------------------------------------------------------------------------------
    def transport(self) -> MemoryTransport:
        """A transport on the composition's bus, for a node built by the caller."""
        return self.bus.transport()

    def add(self, cls: type[Node], name: str, params: Mapping[str, Any] | None = None, *, namespace: str = "",
            remap: Mapping[str, str] | None = None, required: bool = False) -> Node:
        """Build ``cls`` on the composition's bus and clock (its ``setup`` runs now, at the current time)."""
        node = cls(name=name, params=params, transport=self.transport(), clock=self.clock, namespace=namespace,
                   remap=remap, heartbeat_s=self.heartbeat_s)
        return self.adopt(node, required=required)

    def adopt(self, node: Node, *, required: bool = False) -> Node:
        """Run ``node`` (built on :meth:`transport` and :attr:`clock`) as part of the composition."""
        self.nodes.append(node)
        self._inbox_list = None
        self._names.add(node.name)
        if required:
            self.required.add(node.name)
        self.settle()
        return node

    # -- running ---------------------------------------------------------------------------------------
    def request_stop(self) -> None:
        """Stop :meth:`run` after the current event (safe from signal handlers)."""
        self._stop = True

    def settle(self) -> None:
        """Take what came from outside, then let the nodes handle every message in flight until none is left."""
        self._take_outside()
        for _ in range(_MAX_ROUNDS):
            busy = [n for n, t in self._inboxes() if t.inbox]
            if not busy:
                return
            for node in busy:
                node.spin_once(0)
        raise PalpaError("composition: the nodes kept publishing to each other without end")

    def step(self, limit_ns: int | None = None) -> bool:
        """Advance to the next timer deadline and run what is due there; False (time unmoved) when no node has a
        timer left or the next deadline is past ``limit_ns``."""
        dues: list[tuple[int, Node]] = []
        due: int | None = None
        for n in self.nodes:  # one pass: this runs at every instant (~250 a simulated second in the demo)
            d = n.next_timer_due_ns()
            if d is not None:
                dues.append((d, n))
                if due is None or d < due:
                    due = d
        if due is None or (limit_ns is not None and due > limit_ns):
            return False
        self.clock.set(max(due, self.clock.now_ns()))
        now = self.clock.now_ns()
        ready = [node for d, node in dues if d <= now]
        # every timer due now runs before any message sent at this instant is handled, as a node of the lockstep
        # clock does (palpa.timing.simclock): the order of nodes in the composition then does not matter
        for node in ready:
            node.run_timers()
        self.settle()
        self._reap()
        return True

    def run(self, until: Callable[[], bool] | None = None, *, max_sim_s: float | None = None) -> int:
        """Advance until :meth:`request_stop`, a required node ends, every node has ended, ``until()`` is true,
        ``max_sim_s`` of simulated time passed, or (without a bridge) no node has a timer left; then close every
        node. Returns the exit code (the required node's, or 0)."""
        end = None if max_sim_s is None else self.clock.now_ns() + int(max_sim_s * 1e9)
        try:
            self.settle()
            self._reap()
            while not self._stop and self.nodes and not (until is not None and until()):
                if not self.step(end):
                    if end is not None and (due := self._next_due()) is not None and due > end:
                        self.clock.set(max(end, self.clock.now_ns()))
                        break
                    if self.bridge is None:
                        break  # nothing scheduled and no outside that could change that
                    self._wait_outside(_IDLE_WAIT_S)
                    self.settle()
                    self._reap()
        finally:
            self.close()
        return self.exit_code

    def close(self) -> None:
        """Close every node (``on_shutdown`` first, as a stopped process would), each after the others have
        handled what it published while closing (the estimator's last samples reach the map before the map
        writes its files), then the bridge. A node that reports failure as it closes (its exit code) makes the
        composition's exit code 1 if it was 0."""
        self.settle()
        for node in self.nodes:
            node.request_shutdown()
        while self.nodes:
            node = self.nodes.pop(0)
            self._inbox_list = None
            try:
                node.close(0)
            except Exception:  # one node failing to close must not leave the others open
                log.exception("closing %s", node.name)
            if node.exit_code and not self.exit_code:  # it reports, as it stops, that its work failed (an
                self.exit_code = 1  # incomplete map): as a process of its own it would fail the launch so
            self.settle()
        if self.bridge is not None:
            self.bridge.close(500)
            self.bridge = None
            if self._hub is not None:
                self._hub.bridge = None

    # -- internals -------------------------------------------------------------------------------------
    def _pump(self) -> None:
        """Let the nodes handle their input once: a node blocked in a service call waits for the others so."""
        self._take_outside()
        for node, t in self._inboxes():
            if t.inbox:
                node.spin_once(0)

    def _inboxes(self) -> list[tuple[Node, MemoryTransport]]:
        if self._inbox_list is None:  # listed once per change of the node set (every step reads it)
            self._inbox_list = [(n, n.transport) for n in self.nodes if isinstance(n.transport, MemoryTransport)]
        return self._inbox_list

    def _next_due(self) -> int | None:
        dues = [d for n in self.nodes if (d := n.next_timer_due_ns()) is not None]
        return min(dues) if dues else None

    def _reap(self) -> None:
        """Nodes that asked to stop (a scanner that finished) are closed; a required one ends the composition."""
        if not any(n.is_shutdown for n in self.nodes):
            return
        for node in [n for n in self.nodes if n.is_shutdown]:
            self.nodes.remove(node)
            self._inbox_list = None
            self.ended.append((node.name, node.exit_code))
            try:
                node.close(0)
            except Exception:
                log.exception("closing %s", node.name)
            self.settle()
            if node.name in self.required:
                log.info("required node %s ended (exit code %d): stopping the composition", node.name,
                         node.exit_code)
                self.exit_code = node.exit_code
                self._stop = True
            else:
                log.info("%s ended (exit code %d); the others keep running", node.name, node.exit_code)

    def _take_outside(self) -> None:
        if self._hub is not None:
            self._hub.sync_bridge()
        if self.bridge is not None:
            now = time.monotonic_ns()
            if now - self._outside_polled_ns >= _OUTSIDE_POLL_NS:  # a syscall: not at each of ~300 steps a second
                self._outside_polled_ns = now
                self._route_outside(self.bridge.poll(0))

    def _wait_outside(self, timeout_s: float) -> None:
        if self.bridge is not None:
            self._route_outside(self.bridge.poll(timeout_s))

    def _ours(self, frames: list[bytes]) -> bool:
        """Whether an envelope from the bridge is one a composed node sent, back from the proxy: its header names
        one of them, or one of their service clients (``<node>.<id>``, palpa.node.service_client). An echo of a
        request taken in again after the client's next call reads to the server as a publisher's restart, and the
        server would run it twice (a robot sent back to a point it had left: fresh seed 8007 under load)."""
        try:
            headers = parse_envelope(frames).headers
        except DecodeError:
            return False   # not ours: the receiver counts what is wrong with it
        ours = self._names
        return any(h.node in ours or h.node.rpartition(".")[0] in ours for h in headers)

    def _route_outside(self, deliveries: list[Delivery]) -> None:
        for d in deliveries:
            frames = d.frames
            if self._ours(frames):
                continue  # one of ours, back from the proxy
            for t in self.bus.listeners(frames[0]):
                t.inbox.append(d)  # one delivery for every listener (Delivery)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m palpa.timing.compose GRAPH.json`` (or ``--json TEXT``): run a composed graph (a :class:`GraphSpec`) on
    the bus named by ``PALPA_BUS``; SIGINT/SIGTERM stop it. The exit code is the required node's (2: bad graph)."""
    from palpa.targets import load_node_class

    args = list(sys.argv[1:] if argv is None else argv)
    # a composed run allocates fast and frees almost nothing in cycles: collect the youngest objects every 5 000
    # allocations, not 700 (the cyclic collector then takes ~0.02 s of a demo run instead of ~0.08 s)
    gc.set_threshold(5000, 10, 10)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if len(args) == 2 and args[0] == "--json":
        where, text = "--json", args[1].encode()
    elif len(args) == 1:
        where = args[0]
        try:
            with open(args[0], "rb") as f:
                text = f.read()
        except OSError as exc:
            print(f"palpa.timing.compose: {exc}", file=sys.stderr)
            return 2
    else:
        print("usage: python -m palpa.timing.compose GRAPH.json | --json TEXT", file=sys.stderr)
        return 2
    try:
        spec = msgspec.json.decode(text, type=GraphSpec)
        entries = [ComposedNode(**n) for n in spec.nodes]
        classes = [load_node_class(e.target) for e in entries]
        if not wait_for_go():
            log.info("the launcher called the start off: no node was built")
            return 0
        bridge = ZmqTransport(from_env(), TransportOptions.from_env())
    except (msgspec.DecodeError, msgspec.ValidationError, TypeError, PalpaError) as exc:
        print(f"palpa.timing.compose: {where}: {exc}", file=sys.stderr)
        return 2
    comp = Composition(bridge=bridge, heartbeat_s=spec.heartbeat_s)

    def stop(signum: int, frame: FrameType | None) -> None:
        comp.request_stop()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        for e, cls in zip(entries, classes, strict=True):
            comp.add(cls, e.name, e.params, namespace=e.namespace, remap=e.remap, required=e.required)
    except PalpaError as exc:
        print(f"palpa.timing.compose: {exc}", file=sys.stderr)
        comp.close()
        return 2
    gc.freeze()  # what start-up made (modules, classes, the nodes) lives to the end: no collection walks it again
    wall, sim = time.monotonic(), comp.clock.now_ns()
    code = comp.run()
    took = time.monotonic() - wall
    simulated = (comp.clock.now_ns() - sim) / 1e9
    log.info("simulated %.1f s in %.1f s of wall time (%.1fx real time)", simulated, took,
             simulated / took if took > 0 else float("inf"))
    return code


if __name__ == "__main__":
    exit_now(main())  # its files are closed by then: the composition has closed every node
