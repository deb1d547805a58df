"""The event lockstep (palpa.timing.lockstep, palpa.timing.simclock): processes get a composition's timeline."""

from __future__ import annotations

import time

import palpa
from messages import Text
from nodes.demo import Talker
from palpa.runtime_msgs import ClockAck
from palpa.testing import MemoryBus
from palpa.timing.lockstep import EventLockstep, InFlight
from palpa.timing.simclock import ClockSource


def _ack(node: str, next_ns: int, sent: dict[str, int] | None = None, recv: dict[str, int] | None = None,
         subs: list[str] | None = None) -> ClockAck:
    return ClockAck(node=node, sim_ns=0, next_ns=next_ns, sent=sent or {}, recv=recv or {}, subs=subs or [])


def test_time_waits_for_due_timers_and_for_every_message_in_flight() -> None:
    ls = EventLockstep()
    ls.report(_ack("b", 250, subs=["x"]))
    ls.report(_ack("c", 0, subs=["srv/request*"]))
    ls.report(_ack("a", 100, sent={"x": 3}))  # sent 3 before it joined (before b could hear it): not waited for
    assert ls.due(100) == ["a"] and ls.in_flight() is None and ls.next_event_ns() == 100
    ls.report(_ack("a", 200, sent={"x": 5, "srv/request": 1}))  # ran its timer: 2 on x, a service request
    assert ls.due(100) == []
    flying = ls.in_flight()
    assert flying is not None and flying.topic == "x" and flying.subscriber == "b" and flying.missing == 2
    ls.report(_ack("b", 250, recv={"x": 2}, subs=["x"]))
    flying = ls.in_flight()
    assert flying is not None and flying.subscriber == "c" and flying.topic == "srv/request"  # by prefix
    ls.report(_ack("c", 0, recv={"srv/request": 1}, subs=["srv/request*"]))
    assert ls.in_flight() is None and ls.next_event_ns() == 200
    ls.report(_ack("a", 300, sent={"x": 6, "srv/request": 1}))
    ls.report(_ack("d", 400))  # another publisher on x
    ls.leave("a")  # its timers are no longer waited for; what it sent before leaving still is
    assert ls.next_event_ns() == 250 and ls.in_flight() == InFlight("x", "b", 1)
    ls.report(_ack("b", 250, recv={"x": 3}, subs=["x"]))
    assert ls.in_flight() is None
    ls.report(_ack("d", 500, sent={"x": 1}))
    assert ls.in_flight() == InFlight("x", "b", 1)
    ls.report(_ack("a", 600, sent={"x": 2}))  # back, restarted: counts anew
    assert ls.in_flight() == InFlight("x", "b", 1)
    ls.leave("b")  # the subscriber gone: nothing is waited for
    assert ls.in_flight() is None


class _Echo(palpa.Node):
    """Publishes, from its handler, what it hears on ``chatter`` (a reaction: the lockstep must wait for it)."""

    def setup(self) -> None:
        self.out = self.publisher("echo", Text)
        self.subscribe("chatter", Text, lambda m: self.out.publish(Text(text=m.text, stamp_ns=self.clock.now_ns())))


class _Sink(palpa.Node):
    def setup(self) -> None:
        self.heard: list[tuple[int, int]] = []
        """(stamp, simulated time it was handled at) of every echo."""
        self.subscribe("echo", Text, lambda m: self.heard.append((m.stamp_ns, self.clock.now_ns())))


def test_processes_see_timers_at_their_deadlines_and_messages_at_the_instant_sent() -> None:
    """A 10 Hz talker, a node echoing it from its handler, a sink: the clock holds the start until all three have
    joined, ticks only at the talker's deadlines, and moves on only once the echo of each tick reached the sink,
    although the sink is spun after the clock (on sockets: whichever process the machine runs first). After the
    start only the talker gets ticks (on its own topic); the echo and the sink, which have no timers, take each
    instant from the messages they handle at it."""
    bus = MemoryBus()
    clock = ClockSource(params={"time_scale": 1000.0, "rate_hz": 1000.0, "participants": ["talker", "echo", "sink"]},
                        transport=bus.transport(), heartbeat_s=0)
    ticks: list[palpa.runtime_msgs.ClockTick] = []
    spy = palpa.Node(name="spy", transport=bus.transport(), heartbeat_s=0)
    spy.subscribe("_palpa/clock", palpa.runtime_msgs.ClockTick, ticks.append)
    addressed: dict[str, list[palpa.runtime_msgs.ClockTick]] = {n: [] for n in ("talker", "echo", "sink")}
    for name, got in addressed.items():
        spy.subscribe(palpa.runtime_msgs.tick_topic(name), palpa.runtime_msgs.ClockTick, got.append)

    def sim(cls: type[palpa.Node], name: str, **params: object) -> palpa.Node:
        return cls(name=name, params=params, transport=bus.transport(), heartbeat_s=0, sim_clock=True,
                   wait_for_clock_s=0)

    talker = sim(Talker, "talker", rate_hz=10.0)
    assert isinstance(talker, Talker)
    nodes: list[palpa.Node] = [talker, clock]
    deadline = time.monotonic() + 0.3
    while time.monotonic() < deadline:
        for n in nodes:
            n.spin_once(0)
    assert talker.out.seq == 0  # echo and sink not there yet: time has not started
    echo, sink = sim(_Echo, "echo"), sim(_Sink, "sink")
    assert isinstance(sink, _Sink)
    nodes += [echo, sink]
    deadline = time.monotonic() + 20
    while len(sink.heard) < 10 and time.monotonic() < deadline:
        for n in nodes:
            n.spin_once(0)
    spy.spin_once(0)
    start = ticks[0].sim_ns
    assert ticks[0].hold and not ticks[-1].hold  # held, then released (at the same instant)
    assert [t.sim_ns - start for t in addressed["talker"]][:9] == [i * 100_000_000 for i in range(1, 10)]
    assert not addressed["echo"] and not addressed["sink"]
    assert sink.heard[:10] == [(start + i * 100_000_000, start + i * 100_000_000) for i in range(10)]
    for n in [*nodes, spy]:
        n.close(0)


def test_a_lead_mode_clock_gets_an_ack_every_10_ms_of_simulated_time() -> None:
    """Under ``lockstep: lead`` the clock keeps time within a lead of the acks: an idle node acks anyway."""
    bus = MemoryBus()
    node = palpa.Node(name="idle", transport=bus.transport(), heartbeat_s=0, sim_clock=True, wait_for_clock_s=0)
    clock = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    tick = clock.publisher("_palpa/clock", palpa.runtime_msgs.ClockTick)
    acks: list[ClockAck] = []
    clock.subscribe(palpa.runtime_msgs.CLOCK_ACK_TOPIC, ClockAck, acks.append)
    for i in range(10):
        tick.publish(palpa.runtime_msgs.ClockTick(sim_ns=1_000_000_000 + i * 4_000_000, lead=True))
        node.spin_once(0)
    clock.spin_once(0)
    assert [a.sim_ns - 1_000_000_000 for a in acks] == [0, 12_000_000, 24_000_000, 36_000_000]
    node.close(0)
    clock.close(0)


def test_a_node_reports_what_it_handled_before_it_blocks_for_input() -> None:
    """Input a sim-clock node took in is reported before it blocks for more: the clock waits for that report (it once
    waited for the blocking poll's timeout at every simulated instant). A sim-clock node waits for input in its
    blocking poll only (which returns at once when input is there): one poll per wake-up."""
    from palpa.net.transport import Delivery, SendFn
    from palpa.testing import MemoryTransport

    events: list[str] = []

    class Watched(MemoryTransport):
        def poll(self, timeout_s: float) -> list[Delivery]:
            if timeout_s > 0:
                events.append("block")
            return super().poll(timeout_s)

        def sender(self, topic: bytes, direct: bool | None) -> SendFn:
            send = super().sender(topic, direct)

            def sending(frames: list[bytes], latched: bool) -> None:
                events.append(frames[0].decode())
                send(frames, latched)
            return sending  # type: ignore[return-value]

    bus = MemoryBus()
    t = Watched(bus)
    bus._add(t)
    node = palpa.Node(name="n", transport=t, heartbeat_s=0, sim_clock=True, wait_for_clock_s=0)
    clock = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    clock.publisher("_palpa/clock", palpa.runtime_msgs.ClockTick).publish(palpa.runtime_msgs.ClockTick(sim_ns=5))
    node.spin_once(0.01)
    node.spin_once(0.01)
    assert events == ["block", palpa.runtime_msgs.CLOCK_ACK_TOPIC, "block"]
    node.close(0)
    clock.close(0)


def test_a_participant_counts_only_once_every_publisher_heard_its_probe() -> None:
    """A node whose subscriptions a readiness probe confirmed is waited for until every other participant's
    publisher socket has heard that probe; what was sent to it before then is not expected to reach it."""
    ls = EventLockstep()
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, probe="pub/1.1", heard=["pub/1.1"]))
    ls.report(ClockAck(node="sub", sim_ns=0, next_ns=0, subs=["x"], probe="sub/2.1", heard=["sub/2.1"]))
    assert ls.unheard() == ("sub", "pub")
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, sent={"x": 2}, probe="pub/1.1"))  # maybe no route yet
    assert ls.unheard() == ("sub", "pub")
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, sent={"x": 2}, probe="pub/1.1", heard=["sub/2.1"]))
    assert ls.unheard() is None and ls.in_flight() is None  # its accounting starts once it is heard
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=200, sent={"x": 3}, probe="pub/1.1"))
    assert ls.in_flight() == InFlight("x", "sub", 1)
    ls.report(ClockAck(node="late", sim_ns=0, next_ns=0, probe="late/3.1"))
    assert ls.unheard() == ("late", "pub")
    ls.leave("pub")  # the only one that had to hear it
    assert ls.unheard() == ("late", "sub")
    ls.report(ClockAck(node="old", sim_ns=0, next_ns=0))  # no probe (a memory bus): nobody needs to hear it
    ls.report(ClockAck(node="sub", sim_ns=0, next_ns=0, subs=["x"], probe="sub/2.1", heard=["late/3.1"]))
    assert ls.unheard() is None


def test_a_subscriber_counts_on_a_direct_publisher_only_once_it_reached_it() -> None:
    """A topic published direct (no proxy): its subscriber is waited for until it reports that the publisher's
    direct socket answered its probe, whichever joined first; what was sent on it before then is not expected."""
    ls = EventLockstep()
    ls.report(ClockAck(node="sub", sim_ns=0, next_ns=0, subs=["pose"]))
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, direct=["pose"], direct_at="ipc://p"))
    assert ls.unheard() == ("sub", "pub")
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, sent={"pose": 2}, direct=["pose"], direct_at="ipc://p"))
    assert ls.unheard() == ("sub", "pub")
    ls.report(ClockAck(node="sub", sim_ns=0, next_ns=0, subs=["pose"], reached=["ipc://p"]))
    assert ls.unheard() is None and ls.in_flight() is None  # the two sent before may have found no route
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=200, sent={"pose": 3}, direct=["pose"], direct_at="ipc://p"))
    assert ls.in_flight() == InFlight("pose", "sub", 1)
    ls.leave("pub")  # restarted: it binds anew, and its subscribers must reach it again
    ls.report(ClockAck(node="pub", sim_ns=0, next_ns=100, direct=["pose"], direct_at="ipc://q"))
    ls.report(ClockAck(node="other", sim_ns=0, next_ns=0, subs=["map"]))  # takes nothing direct: not waited for
    assert ls.unheard() == ("sub", "pub")
    ls.report(ClockAck(node="sub", sim_ns=0, next_ns=0, subs=["pose"], recv={"pose": 1}, reached=["ipc://q"]))
    assert ls.unheard() is None and ls.in_flight() is None
    ls.report(ClockAck(node="sub2", sim_ns=0, next_ns=0, subs=["pose"]))  # joins after the publisher
    assert ls.unheard() == ("sub2", "pub")
    ls.assume_heard()  # the clock's stall timeout
    assert ls.unheard() is None


def test_the_clock_starts_time_only_once_the_participants_heard_each_other() -> None:
    bus = MemoryBus()
    clock = ClockSource(params={"time_scale": 1000.0, "participants": ["a", "b"]}, transport=bus.transport(),
                        heartbeat_s=0)
    a, b = (palpa.Node(name=n, transport=bus.transport(), heartbeat_s=0) for n in "ab")  # each acks for itself
    acks = {n.name: n.publisher(palpa.runtime_msgs.CLOCK_ACK_TOPIC, ClockAck) for n in (a, b)}
    ticks: list[palpa.runtime_msgs.ClockTick] = []
    a.subscribe(palpa.runtime_msgs.CLOCK_TOPIC, palpa.runtime_msgs.ClockTick, ticks.append)

    def spin() -> None:
        for _ in range(5):
            clock.spin_once(0)
            a.spin_once(0)

    acks["a"].publish(ClockAck(node="a", sim_ns=0, next_ns=10, probe="a/1.1", heard=["a/1.1"]))
    acks["b"].publish(ClockAck(node="b", sim_ns=0, next_ns=10, probe="b/2.1", heard=["a/1.1", "b/2.1"]))
    spin()
    assert ticks and all(t.hold for t in ticks)  # a has not heard b: b might miss what a sends first
    acks["a"].publish(ClockAck(node="a", sim_ns=0, next_ns=10, probe="a/1.1", heard=["b/2.1"]))
    spin()
    assert not ticks[-1].hold
    for n in (clock, a, b):
        n.close(0)


def test_the_bookkeeping_kept_report_by_report_agrees_with_a_recount() -> None:
    """What is in flight is kept up to date at each report (the clock asks at every instant); a recount from the
    members' bases after random joins, reports, resubscriptions, leaves and restarts gives the same."""
    import random

    rng = random.Random(5)
    topics = ["a", "b", "srv/x", "srv/y"]
    ls = EventLockstep()
    sent: dict[str, dict[str, int]] = {}
    recv: dict[str, dict[str, int]] = {}
    subs: dict[str, list[str]] = {}
    for step in range(3000):
        node = rng.choice(["n0", "n1", "n2", "n3"])
        r = rng.random()
        if r < 0.03:
            ls.leave(node)
            sent.pop(node, None), recv.pop(node, None), subs.pop(node, None)
            continue
        if r < 0.04:
            ls.restart_accounting()
            continue
        if node not in subs or r < 0.08:
            subs[node] = rng.sample(["a", "b", "srv/*"], rng.randint(0, 3))
        s, v = sent.setdefault(node, {}), recv.setdefault(node, {})
        t = rng.choice(topics)
        s[t] = s.get(t, 0) + rng.randint(0, 2)
        t = rng.choice(topics)
        v[t] = v.get(t, 0) + rng.randint(0, 2)
        ls.report(_ack(node, 10, sent=dict(s), recv=dict(v), subs=list(subs[node])))
        recount = {
            (name, topic) for name, m in ls.members.items() for topic, n in ls._sent.items()
            if m.wants(topic) and (n - m.base.get(topic, 0)) - (m.ack.recv.get(topic, 0) - m.base_recv.get(topic, 0)) > 0
        }
        assert set(ls._short) == recount, step
        flying = ls.in_flight()
        assert (flying is None) == (not recount)
