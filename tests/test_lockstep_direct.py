"""A lockstep's own traffic (ticks to the nodes, acks to the clock) goes straight between the clock and its nodes
(palpa.net.direct): not through the proxy, and not to a recorder that takes every topic but those."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

import palpa
from messages import Text
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.net.direct import DIRECTORY_PREFIX
from palpa.net.transport import Delivery, ZmqTransport
from palpa.record.reader import iter_bag
from palpa.record.recorder import Recorder
from palpa.runtime_msgs import CLOCK_ACK_TOPIC
from palpa.timing.simclock import ClockSource
from tests.procs import short_ipc_base, wait_until
from tests.test_readiness import REACH_PROBES, SubscriptionGate, through_gate

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

LOCKSTEP_EXCLUDE = ["_palpa/clock.*", "_palpa/tick/.*", "_palpa/lockstep"]  # launch/scan_sim.yaml's record:


class _Ticker(palpa.Node):
    def setup(self) -> None:
        self.out = self.publisher("chatter", Text)
        self.ran: list[int] = []
        self.timer(0.01, self.tick)

    def tick(self) -> None:
        self.ran.append(self.clock.now_ns())
        self.out.publish(Text(text=str(len(self.ran)), stamp_ns=self.clock.now_ns()))


class _DirectTicker(_Ticker):
    def setup(self) -> None:
        self.out = self.publisher("chatter", Text, direct=True)
        self.ran = []
        self.timer(0.01, self.tick)


class _Listener(palpa.Node):
    def setup(self) -> None:
        self.heard = self.subscribe("chatter", Text)


class _Graph:
    """A bus and in-process nodes on it, spun in turn; all closed at the end."""

    def __init__(self) -> None:
        self.bus = Bus(BusAddress.parse(f"ipc://{short_ipc_base()}"))
        self.address = self.bus.start()
        self.nodes: list[palpa.Node] = []

    def clock(self) -> ClockSource:
        clock = ClockSource("clock", {"time_scale": 1000.0, "participants": ["ticker"]}, bus=self.address,
                            heartbeat_s=0)
        self.nodes.append(clock)
        return clock

    def ticker(self) -> _Ticker:
        ticker = _Ticker("ticker", bus=self.address, sim_clock=True, heartbeat_s=0, wait_for_clock_s=0)
        self.nodes.append(ticker)
        return ticker

    def spin(self) -> None:
        for n in self.nodes:
            n.spin_once(0.001)

    def close(self) -> None:
        try:
            for n in reversed(self.nodes):
                n.close(0)
        finally:
            self.bus.stop()


@pytest.fixture
def graph() -> Iterator[_Graph]:
    g = _Graph()
    try:
        yield g
    finally:
        g.close()


def test_ticks_and_acks_go_past_the_proxy_and_the_recorder(graph: _Graph, tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    rec = Recorder("recorder", {"output": str(out), "exclude": LOCKSTEP_EXCLUDE}, bus=graph.address, heartbeat_s=0)
    graph.nodes.append(rec)
    at_recorder: list[bytes] = []
    poll = rec.transport.poll

    def spy(timeout_s: float) -> list[Delivery]:
        got = poll(timeout_s)
        at_recorder.extend(d.frames[0] for d in got)
        return got

    rec.transport.poll = spy  # type: ignore[method-assign]
    graph.clock()
    ticker = graph.ticker()
    wait_until(lambda: len(ticker.ran) >= 30, 30, "30 lockstep instants of the ticker's timer", step=graph.spin)
    wait_until(lambda: at_recorder.count(b"chatter") >= 20, 10, "chatter at the recorder", step=graph.spin)
    rec.close(0)  # the file finished
    steps = [b - a for a, b in zip(ticker.ran, ticker.ran[1:], strict=False)]
    assert set(steps) == {10_000_000}  # every 10 ms of simulated time, none skipped: the lockstep ran
    lockstep = [t for t in at_recorder if t.startswith((b"_palpa/lockstep", b"_palpa/tick/"))]
    assert not lockstep, lockstep[:5]
    assert sum(m.topic == "chatter" for m in iter_bag([out])) >= 20


def test_a_node_acks_only_once_the_clock_listens_on_its_direct_socket(graph: _Graph) -> None:
    """An ack sent before the clock connected would be lost, and the clock wait for that node for good: with the
    clock's connection to the node's direct socket held back, time starts only once it is made."""
    t = graph.clock().transport
    assert isinstance(t, ZmqTransport)
    takes = t._takes_direct
    held = [True]
    t._takes_direct = lambda key: not held[0] and takes(key)  # type: ignore[method-assign]
    ticker = graph.ticker()
    clock_time = ticker._topic_clock
    assert clock_time is not None
    wait_until(lambda: clock_time.started, 10, "the clock's held start at the ticker", step=graph.spin)
    for _ in range(50):
        graph.spin()
    assert not ticker.ran  # the clock has not heard the ticker: time has not started
    held[0] = False
    t._to_cache([b"GET", DIRECTORY_PREFIX + CLOCK_ACK_TOPIC.encode()])  # the announcement, again
    wait_until(lambda: len(ticker.ran) >= 5, 10, "time to start and run the ticker's timer", step=graph.spin)


def test_a_node_not_yet_connected_to_the_clock_gets_its_instants_through_the_bus(graph: _Graph) -> None:
    """The clock sends an instant straight to a node only once the node's subscription has reached its direct
    socket; until then (here: for good) the broadcast through the bus carries it, and time does not stall."""
    graph.clock()
    ticker = graph.ticker()
    ticker.transport._takes_direct = lambda key: False  # type: ignore[attr-defined]
    wait_until(lambda: len(ticker.ran) >= 10, 10, "the ticker's timer to run", step=graph.spin)


def test_time_waits_for_a_subscriber_to_reach_a_direct_publisher_that_joins_late(
        graph: _Graph, monkeypatch: pytest.MonkeyPatch) -> None:
    """A publisher of a direct topic joins a running lockstep while its subscriber's connection to it is slow (its
    subscriptions held at a gate): simulated time does not move until the publisher has them, so the message the
    publisher sends at its first instant reaches the subscriber."""
    clock = ClockSource("clock", {"time_scale": 1000.0, "participants": ["listener"]}, bus=graph.address,
                        heartbeat_s=0)
    graph.nodes.append(clock)
    listener = _Listener("listener", bus=graph.address, sim_clock=True, heartbeat_s=0, wait_for_clock_s=0)
    graph.nodes.append(listener)
    sim = listener._sim_time
    assert sim is not None
    wait_until(lambda: not sim.holds_timers, 10, "simulated time to start", step=graph.spin)
    # not among the participants: the clock believes its acks once its heartbeats are heard (palpa.timing.ackgate)
    ticker = _DirectTicker("ticker", bus=graph.address, sim_clock=True, heartbeat_s=1.0, wait_for_clock_s=0)
    graph.nodes.append(ticker)
    t, lt = ticker.transport, listener.transport
    assert isinstance(t, ZmqTransport) and isinstance(lt, ZmqTransport) and ticker.out.direct
    with SubscriptionGate(t.direct_endpoint) as gate:
        through_gate(monkeypatch, t.direct_endpoint, gate, only=lt._sub)
        # the clock, once it has the ticker, either waits for the listener to reach it or moves time on
        wait_until(lambda: ticker.ran or clock._events.unheard() == ("listener", "ticker"), 10,
                   "the clock to take the ticker in", step=graph.spin)
        wait_until(lambda: ticker.ran or gate.holds(REACH_PROBES), 10, "the listener's probe held",
                   step=graph.spin)
        for _ in range(50):
            graph.spin()
        assert not ticker.ran, "time moved on while the listener had not reached the ticker"
        gate.open()
        wait_until(lambda: listener.heard.queue, 10, "a message of the ticker at the listener", step=graph.spin)
        assert listener.heard.queue[0].text == "1", "the ticker's first message was lost"
