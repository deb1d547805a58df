"""Unit tests of the runtime: addresses, params, sequence tracking, and node behaviour on the in-memory bus."""

from __future__ import annotations

import socket
from typing import Any

import msgspec
import pytest

import palpa
from messages import Text
from nodes.demo import Listener, Talker
from palpa.errors import BusError, ParamError
from palpa.net.address import BusAddress
from palpa.net.wire import Header, SequenceTracker, TopicStats, encode_header
from palpa.testing import MemoryBus, NodeHarness


def test_address_forms() -> None:
    a = BusAddress.parse("ipc:///tmp/palpa-x")
    assert (a.pub, a.sub, a.latch) == ("ipc:///tmp/palpa-x.pub", "ipc:///tmp/palpa-x.sub", "ipc:///tmp/palpa-x.latch")
    t = BusAddress.parse("tcp://127.0.0.1:7400")
    assert (t.pub, t.sub, t.latch) == ("tcp://127.0.0.1:7400", "tcp://127.0.0.1:7401", "tcp://127.0.0.1:7402")
    assert BusAddress.parse(str(t)) == t


@pytest.mark.parametrize("bad", ["ipc://", "tcp://nohost", "tcp://h:abc", "udp://x", "pub=a;sub=b",
                                 "ipc:///tmp/" + "x" * 120, "tcp://127.0.0.1:0"])
def test_address_errors_are_clear(bad: str) -> None:
    with pytest.raises(BusError, match="bus address"):
        BusAddress.parse(bad)


def test_params_validated_with_names() -> None:
    with pytest.raises(ParamError, match=r"node 'talker': parameter 'rate_hz': Expected `float`, got `str`"):
        Talker(params={"rate_hz": "fast"}, transport=MemoryBus().transport())
    with pytest.raises(ParamError, match="unknown field `rte_hz`.*declared parameters: rate_hz"):
        Talker(params={"rte_hz": 3}, transport=MemoryBus().transport())
    node = Talker(params={"rate_hz": 5}, transport=MemoryBus().transport())
    assert node.params.rate_hz == 5.0


def test_sequence_tracker_classifies() -> None:
    tr, st = SequenceTracker(), TopicStats()
    assert [tr.observe("t", "n", s, st) for s in (1, 2, 5, 5, 6, 1)] == [True, True, True, False, True, True]
    assert (st.received, st.gaps, st.duplicates, st.restarts) == (5, 2, 1, 1)
    # two publishers on one topic are tracked separately
    assert tr.observe("t", "m", 1, st) and st.gaps == 2


def test_talker_listener_on_memory_bus() -> None:
    bus = MemoryBus()
    h = NodeHarness(Listener, bus=bus)
    talker = Talker(params={"rate_hz": 10, "count": 3}, transport=bus.transport(), clock=h.clock, heartbeat_s=0)
    for _ in range(5):
        talker.spin_once(0)
        h.advance(0.1)
    assert [m.text for m in h.published("chatter_len")] == ["7", "7", "7"]
    assert talker.is_shutdown and talker.exit_code == 0


def test_exact_topic_match_no_prefix_leak() -> None:
    h = NodeHarness(Listener)
    h.publish("chatterbox", Text(text="not for you"))
    h.publish("chatter", Text(text="yes"))
    assert h.node.heard == 1


def test_bad_frames_are_counted_not_fatal() -> None:
    h = NodeHarness(Listener)
    good = encode_header(Header(type="Text", seq=1, stamp=1, node="x"))
    h.publish_raw([b"chatter"])  # too few frames
    h.publish_raw([b"chatter", b"\xff\x00", b""])  # bad header
    h.publish_raw([b"chatter", encode_header(Header(type="RobotPose", seq=2, stamp=1, node="x")),
                   msgspec.msgpack.encode({"text": "wrong type"})])
    h.publish_raw([b"chatter", encode_header(Header(type="Text", seq=3, stamp=1, node="x")),
                   msgspec.msgpack.encode({"text": 42})])
    stats = h.node.counters()["chatter"]
    assert stats.last_error == "Text: Expected `str`, got `int` - at `$.text`"
    h.publish_raw([b"chatter", good, b"\xc1"])  # never-used msgpack byte
    assert stats.decode_errors == 5
    h.publish("chatter", Text(text="still alive"))
    assert h.node.heard == 1


def test_handler_type_from_annotation_and_iterator_form() -> None:
    bus = MemoryBus()
    script = palpa.Node(name="script", transport=bus.transport(), heartbeat_s=0)
    sub = script.subscribe("chatter", Text)
    talker = Talker(params={"count": 2}, transport=bus.transport(), heartbeat_s=0)
    talker.spin_once(0)
    got = [sub.next(timeout_s=0.5) for _ in range(1)]
    assert got[0] is not None and got[0].text == "hello 1"

    class Bad(palpa.Node):
        def setup(self) -> None:
            self.subscribe("x", self.handler)

        def handler(self, msg: int) -> None: ...

    with pytest.raises(TypeError, match="no Message-typed parameter"):
        Bad(transport=bus.transport())


def test_latched_topics_reach_late_joiners_once() -> None:
    bus = MemoryBus()
    pub_node = palpa.Node(name="planner", transport=bus.transport(), heartbeat_s=0)
    pub = pub_node.publisher("plan", Text, latched=True)
    pub.publish(Text(text="v1"))
    pub.publish(Text(text="v2"))
    late = palpa.Node(name="late", transport=bus.transport(), heartbeat_s=0)
    sub = late.subscribe("plan", Text)
    assert sub.next(0.1) == Text(text="v2")
    assert sub.next(0.0) is None


def test_remap_and_namespace() -> None:
    h = NodeHarness(Listener, namespace="left", remap={"chatter": "/talk"})
    h.publish("talk", Text(text="abc"))
    assert h.node.heard == 1
    assert [m.text for m in h.published("left/chatter_len")] == ["3"]


def test_handler_exception_is_logged_and_node_survives() -> None:
    class Fragile(palpa.Node):
        def setup(self) -> None:
            self.seen = 0
            self.subscribe("chatter", self.on_text)

        def on_text(self, msg: Text) -> None:
            self.seen += 1
            raise RuntimeError("boom")

    h = NodeHarness(Fragile)
    h.publish("chatter", Text(text="a"))
    h.publish("chatter", Text(text="b"))
    assert h.node.seen == 2 and h.node.handler_errors == 2
    logs = [m for m in h.published("_palpa/log") if m.level == "ERROR"]
    assert logs and "boom" in logs[0].text


def test_publisher_refuses_wrong_type() -> None:
    node = palpa.Node(name="n", transport=MemoryBus().transport(), heartbeat_s=0)
    pub = node.publisher("chatter", Text)
    with pytest.raises(TypeError, match="carries Text"):
        pub.publish(palpa.runtime_msgs.ClockTick(sim_ns=1))  # type: ignore[arg-type]


def test_sim_clock_follows_clock_topic() -> None:
    from palpa.runtime_msgs import ClockTick

    bus = MemoryBus()
    node = Talker(params={"rate_hz": 10}, transport=bus.transport(), heartbeat_s=0, sim_clock=True,
                  wait_for_clock_s=0)
    ticker = palpa.Node(name="player", transport=bus.transport(), heartbeat_s=0)
    pub = ticker.publisher("_palpa/clock", ClockTick)
    spy = palpa.Node(name="spy", transport=bus.transport(), heartbeat_s=0)
    sub = spy.subscribe("chatter", Text)
    for i in range(10):
        pub.publish(ClockTick(sim_ns=1_000_000_000 + i * 50_000_000))
        node.spin_once(0)
    spy.spin_once(0)
    # 0.45 s of sim time at 10 Hz: first tick at t0 then every 100 ms, none before time existed
    assert [m.stamp_ns for m in sub.queue] == [1_000_000_000 + i * 100_000_000 for i in range(5)]


def test_batched_publisher_delivers_in_order_after_each_callback() -> None:
    class Burst(palpa.Node):
        def setup(self) -> None:
            self.out = self.publisher("burst", Text, batch=8)
            self.subscribe("go", self.on_go)

        def on_go(self, msg: Text) -> None:
            for i in range(20):
                self.out.publish(Text(text=str(i)))

    bus = MemoryBus()
    h = NodeHarness(Burst, bus=bus)
    sent: list[int] = []
    orig = bus._route

    def spy(frames, latched):  # type: ignore[no-untyped-def]
        if frames[0] == b"burst":
            header = msgspec.msgpack.decode(frames[1])
            sent.append(len(header) if isinstance(header, list) else 1)
        orig(frames, latched)

    bus._route = spy  # type: ignore[method-assign]
    h.publish("go", Text(text="now"))
    assert [m.text for m in h.published("burst")] == [str(i) for i in range(20)]
    assert sent == [8, 8, 4]  # two full batches, the rest flushed when the callback returned


def test_malformed_batch_is_counted() -> None:
    h = NodeHarness(Listener)
    hdrs = msgspec.msgpack.encode([Header(type="Text", seq=1, stamp=1, node="x"),
                                   Header(type="Text", seq=2, stamp=1, node="x")])
    h.publish_raw([b"chatter", hdrs, msgspec.msgpack.encode([{"text": "only one payload"}])])
    assert h.node.counters()["chatter"].decode_errors == 1
    assert "batch header lists 2 messages but 1 payloads follow" in h.node.counters()["chatter"].last_error


def test_clock_source_lockstep_holds_for_the_slowest_node(monkeypatch: pytest.MonkeyPatch,
                                                          caplog: pytest.LogCaptureFixture) -> None:
    from palpa.runtime_msgs import CLOCK_ACK_TOPIC, ClockAck

    wall, bus, src = clock_source(monkeypatch)
    wall[0] = 100_000_000  # 0.1 s wall at 2x: free running, 0.2 s simulated
    assert src.sim_now_ns() == 1_200_000_000
    laggard = palpa.Node(name="slow", transport=bus.transport(), heartbeat_s=0)
    ack = laggard.publisher(CLOCK_ACK_TOPIC, ClockAck)
    ack.publish(ClockAck(node="slow", sim_ns=1_150_000_000))
    src.spin_once(0)
    wall[0] = 200_000_000
    assert src.sim_now_ns() == 1_200_000_000  # held: the slow node is 50 ms behind, more than the 20 ms lead
    ack.publish(ClockAck(node="slow", sim_ns=1_200_000_000))  # caught up (an ack past the clock's time is refused)
    src.spin_once(0)
    wall[0] = 300_000_000
    assert src.sim_now_ns() == 1_220_000_000  # may lead the slowest node by 20 ms, no more
    wall[0] = 300_000_000 + 3_000_000_000  # silent for 3 s: slow, not gone (no process to check): still holding
    assert src.sim_now_ns() == 1_220_000_000
    wall[0] = 300_000_000 + 30_000_000_000  # silent for participant_timeout_s: it no longer holds the clock
    assert src.sim_now_ns() == 1_220_000_000 + 2 * 27_000_000_000
    wall[0] += 100_000_000
    src.sim_now_ns()
    dropped = [r for r in caplog.records if "slow not heard" in r.getMessage()]
    assert len(dropped) == 1 and dropped[0].levelname == "WARNING"  # said once, not on every tick


def clock_source(monkeypatch: pytest.MonkeyPatch) -> tuple[list[int], MemoryBus, Any]:
    """A clock source (2x, 20 ms lead, simulated time from 1 s) on a memory bus, its wall clock ``wall[0]``."""
    from palpa.timing import simclock

    wall = [0]
    monkeypatch.setattr(simclock.time, "monotonic_ns", lambda: wall[0])
    monkeypatch.setattr(simclock.time, "time_ns", lambda: 1_000_000_000)
    bus = MemoryBus()
    src = simclock.ClockSource(params={"time_scale": 2.0, "max_lead_s": 0.02}, transport=bus.transport(),
                               heartbeat_s=0)
    return wall, bus, src


def _lockstep(monkeypatch: pytest.MonkeyPatch) -> tuple[list[int], Any, Any, Any]:
    """A clock source and a participant 'slow' (pid 4242 on this host) that acked 1.1 s of simulated time:
    (wall, source, ack publisher, heartbeat publisher)."""
    from palpa.runtime_msgs import CLOCK_ACK_TOPIC, ClockAck, Heartbeat

    wall, bus, src = clock_source(monkeypatch)
    wall[0] = 50_000_000
    assert src.sim_now_ns() == 1_100_000_000  # the time the node acks (an ack past the clock's time is refused)
    peer = palpa.Node(name="slow", transport=bus.transport(), heartbeat_s=0)
    ack = peer.publisher(CLOCK_ACK_TOPIC, ClockAck)
    hb = peer.publisher("_palpa/heartbeat", Heartbeat)
    ack.publish(ClockAck(node="slow", sim_ns=1_100_000_000))
    hb.publish(Heartbeat(node="slow", pid=4242, host=socket.gethostname(), publishes={}, subscribes={}, counters={},
                         sent={}, uptime_s=1.0))
    src.spin_once(0)
    return wall, src, ack, hb


def test_lockstep_waits_for_a_silent_node_whose_process_is_alive(monkeypatch: pytest.MonkeyPatch) -> None:
    """A CPU-starved node (no ack for minutes of wall time) whose process lives holds simulated time back."""
    wall, src, _, _ = _lockstep(monkeypatch)
    src.pid_alive = lambda pid: pid == 4242
    for wall[0] in (1_000_000_000, 10_000_000_000, 300_000_000_000):
        assert src.sim_now_ns() == 1_120_000_000  # 20 ms ahead of its last ack, however long it is silent


def test_lockstep_drops_a_node_whose_process_is_gone_or_that_left(monkeypatch: pytest.MonkeyPatch) -> None:
    """Its process gone: dropped once silent for check_after_s (2 s), not before; a 'leaving' ack: at once."""
    from palpa.runtime_msgs import ClockAck

    wall, src, ack, _ = _lockstep(monkeypatch)
    src.pid_alive = lambda pid: False
    wall[0] = 1_900_000_000
    assert src.sim_now_ns() == 1_120_000_000  # silent < 2 s: not checked yet
    wall[0] = 2_100_000_000
    assert src.sim_now_ns() == 1_120_000_000 + 2 * 200_000_000  # gone: time runs free
    ack.publish(ClockAck(node="slow", sim_ns=1_500_000_000))  # it acks again: it takes part again
    src.spin_once(0)
    src.pid_alive = lambda pid: True
    wall[0] = 3_000_000_000
    assert src.sim_now_ns() == 1_520_000_000
    ack.publish(ClockAck(node="slow", sim_ns=2_000_000_000, leaving=True))
    src.spin_once(0)
    wall[0] = 3_100_000_000
    assert src.sim_now_ns() == 1_520_000_000 + 2 * 100_000_000  # it left: not waited for


def test_a_sim_clock_node_says_it_leaves_as_it_closes() -> None:
    """Its last clock ack carries 'leaving', so the lockstep clock stops waiting for it at once."""
    from palpa.runtime_msgs import CLOCK_ACK_TOPIC, ClockAck

    bus = MemoryBus()
    node = palpa.Node(name="sim", transport=bus.transport(), sim_clock=True, wait_for_clock_s=0, heartbeat_s=0)
    h = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    acks: list[ClockAck] = []
    h.subscribe(CLOCK_ACK_TOPIC, ClockAck, acks.append)
    node.close(0)
    h.spin_once(0)
    assert [a.leaving for a in acks] == [True] and acks[0].node == "sim"


def test_a_setup_that_takes_a_name_the_node_keeps_its_state_in_is_refused_at_once() -> None:
    """A subclass's ``self._timers = []`` in setup used to break the node later (its timers never ran), far from
    the cause. Names the subclass set before calling Node.__init__, and flags and counters, are its own business."""
    from palpa.errors import PalpaError

    class Clobbers(palpa.Node):
        def setup(self) -> None:
            self._timers = []   # palpa.Node's timers live here

    bus = MemoryBus()
    with pytest.raises(PalpaError, match=r"node 'clobbers': Clobbers.setup\(\) replaced '_timers'"):
        Clobbers(transport=bus.transport(), heartbeat_s=0)

    class OwnsItsNames(palpa.Node):
        def __init__(self, **kw: Any) -> None:
            self._late: object = None   # set before Node.__init__, replaced in setup: its own
            super().__init__(**kw)

        def setup(self) -> None:
            self._late = object()
            self._buffer = [1, 2]   # a new name: fine
            self.request_shutdown(3)   # flags and exit codes change in setup: fine

    node = OwnsItsNames(transport=bus.transport(), heartbeat_s=0)
    assert node.is_shutdown and node.exit_code == 3 and node._late is not None
    node.close()


class _Slow(palpa.Node):
    """A sim-clock node whose only timer fires every two simulated minutes (a periodic save, a status line)."""

    def setup(self) -> None:
        self.fired: list[int] = []
        self.timer(120.0, lambda: self.fired.append(self.clock.now_ns()))


def test_a_timer_further_off_than_the_bound_still_fires() -> None:
    """The event lockstep ticks a node at its own next deadline: for a 2-minute timer that is 120 s on, past the 60 s
    bound, and it was refused for good (the timer never fired). A jump that passes none of the node's timers is
    taken; one that passes a timer is still refused, as is a message's instant past it."""
    from palpa.runtime_msgs import ClockTick

    bus = MemoryBus()
    node = _Slow(name="slow", transport=bus.transport(), heartbeat_s=0, sim_clock=True, wait_for_clock_s=0,
                 sim_clock_timeout_s=0)
    clock = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    pub = clock.publisher("_palpa/clock", ClockTick)
    t0 = 10**9
    pub.publish(ClockTick(sim_ns=t0))  # time starts: the timer is due at t0 + 120 s
    node.spin_once(0)
    for k in (1, 2):
        pub.publish(ClockTick(sim_ns=t0 + k * 120 * 10**9))  # the lockstep's tick at its deadline
        node.spin_once(0)
        assert node.fired == [t0 + i * 120 * 10**9 for i in range(1, k + 1)]
    assert node.sim_time is not None and node.sim_time.refused_jumps == 0
    now = node.clock.now_ns()
    pub.publish(ClockTick(sim_ns=now + 3600 * 10**9))  # past its next deadline (now + 120 s): refused
    node.spin_once(0)
    assert node.clock.now_ns() == now and len(node.fired) == 2 and node.sim_time.refused_jumps == 1
    forger = palpa.Node(name="forger", transport=bus.transport(), heartbeat_s=0)
    node.subscribe("chatter", Text)
    forger.publish_raw("chatter", Header(type="Text", seq=1, stamp=1, node="forger", at=now + 3600 * 10**9),
                       msgspec.msgpack.encode(Text(text="hi")))
    node.spin_once(0)
    assert node.clock.now_ns() == now and node.sim_time.refused_jumps == 2
    for n in (node, clock, forger):
        n.close(0)
