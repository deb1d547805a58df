"""The Player node on the in-memory bus: identity (type, seq, publisher) and payload bytes kept, timing, topic
selection, remap, start offset, latched re-publication, split sets, loop and the replay clock."""

from __future__ import annotations

import threading
from pathlib import Path

import msgspec
import pytest

from messages import Text
from palpa.errors import ParamError
from palpa.net.transport import Delivery
from palpa.node.node import Node, RawMessage
from palpa.record.format import BagError
from palpa.record.player import Player
from palpa.record.recorder import Recorder
from palpa.record.testing import Rec, write_bag
from palpa.runtime_msgs import CLOCK_TOPIC, ClockTick
from palpa.testing import MemoryBus, MemoryTransport, NodeHarness
from tests.procs import wait_until

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


def _text(s: str) -> bytes:
    return msgspec.msgpack.encode(Text(text=s, stamp_ns=7))


def _bag(path: Path) -> Path:
    msgs = [Rec("calibration", T0, _text("cal"), 1, node="cal_node", latched=True)]
    msgs += [Rec("chatter", T0 + (i + 1) * 5 * MS, _text(f"c{i}"), i + 1, publish_time=T0 + i) for i in range(20)]
    msgs += [Rec("other", T0 + 50 * MS, _text("o"), 1, node="x")]
    return write_bag(path, sorted(msgs, key=lambda m: m.log_time))


def _play(params: dict[str, object]) -> tuple[Player, list[RawMessage]]:
    bus = MemoryBus()
    got: list[RawMessage] = []
    probe = Node(name="probe", transport=bus.transport(), heartbeat_s=0)
    probe.subscribe_raw("", got.append)
    player = Player(name="player", params={"exit_delay_s": 0.0, **params}, transport=bus.transport(), heartbeat_s=0)
    try:
        player.spin()
        probe.spin_once(0)
    finally:
        player.close(0)
        probe.close(0)
    return player, got


def test_identity_payloads_and_timing(tmp_path: Path) -> None:
    player, got = _play({"file": str(_bag(tmp_path / "b.mcap"))})
    assert player.is_shutdown and player.exit_code == 0
    chatter = [r for r in got if r.topic == "chatter"]
    assert [(r.header.type, r.header.seq, r.header.node) for r in chatter] == [("Text", i, "talker")
                                                                              for i in range(1, 21)]
    assert [r.payload for r in chatter] == [_text(f"c{i}") for i in range(20)]
    stamps = [r.header.stamp for r in chatter]  # the new publish times; recorded every 5 ms
    # on schedule up to the lateness the player reports (a loaded machine makes it late, never early;
    # precision is measured by test_record_graph)
    assert (stamps[-1] - stamps[0]) / MS == pytest.approx(19 * 5.0, abs=3.0 + 1e3 * player.late_max_s)
    assert stamps == sorted(stamps) and chatter[0].header.stamp > 1_700_000_000_000_000_000 + 10**15
    cal = [r for r in got if r.topic == "calibration"]
    assert len(cal) == 1 and cal[0].header.latched and cal[0].header.node == "cal_node"
    assert {r.topic for r in got} == {"calibration", "chatter", "other"}


def test_rate_topics_remap_and_start_offset(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b.mcap")
    player, got = _play({"file": str(bag), "topics": ["chatter", "calib.*"], "remap": {"chatter": "replayed"},
                         "start_offset_s": 0.05, "rate": 4.0})
    topics = [r.topic for r in got]
    assert topics[0] == "calibration"  # latched state before the offset is delivered first
    replayed = [r for r in got if r.topic == "replayed"]
    assert [r.header.seq for r in replayed] == list(range(10, 21))  # log time >= first + 50 ms
    stamps = [r.header.stamp for r in replayed]
    assert (stamps[-1] - stamps[0]) / MS == pytest.approx(50 / 4.0, abs=3.0 + 1e3 * player.late_max_s)
    assert "other" not in topics and "chatter" not in topics


def test_split_recording_plays_once_in_order(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    h = NodeHarness(Recorder, {"output": str(out), "split_size_mb": 0.001})
    h.publish("calibration", Text(text="latched cal"), latched=True)
    for k in range(90):
        h.publish("chatter", Text(text=f"message {k:03d} " + "y" * 40))
        if k % 30 == 29:
            h.advance(0.5)
    h.close()
    _, got = _play({"file": str(out), "rate": 100.0})
    assert len([r for r in got if r.topic == "calibration"]) == 1
    assert [msgspec.msgpack.decode(r.payload)["text"] for r in got if r.topic == "chatter"] == \
        [f"message {k:03d} " + "y" * 40 for k in range(90)]


def test_loop_and_clock(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b.mcap")
    bus = MemoryBus()
    got: list[RawMessage] = []
    probe = Node(name="probe", transport=bus.transport(), heartbeat_s=0)
    probe.subscribe_raw("", got.append)
    player = Player(name="player", params={"file": str(bag), "loop": True, "clock": True, "clock_hz": 500.0,
                                           "rate": 2.0}, transport=bus.transport(), heartbeat_s=0)
    thread = threading.Thread(target=player.spin)
    thread.start()
    try:
        wait_until(lambda: player.passes >= 2 or not thread.is_alive(), 5, "two passes of the loop",
                   step=lambda: thread.join(0.1))
    finally:
        player.request_shutdown()
        thread.join(5)
        player.close(0)
    assert not thread.is_alive() and player.passes >= 2
    probe.spin_once(0)
    probe.close(0)
    chatter = [r.header.seq for r in got if r.topic == "chatter"]
    assert chatter[:40] == list(range(1, 21)) * 2  # loops restart the recorded sequence numbers
    ticks = [msgspec.msgpack.decode(r.payload, type=ClockTick).sim_ns for r in got if r.topic == CLOCK_TOPIC]
    start = ticks.index(T0)  # the clock ran up to the recording's start while the player got ready
    run_up, playing = ticks[:start], ticks[start:]
    assert run_up == sorted(run_up) and all(T0 - 11 * 10**9 < t < T0 for t in run_up)
    assert len(playing) >= 10
    assert all(T0 <= t <= T0 + 200 * MS for t in playing)  # recorded time, not wall time
    jumps_back = [i for i in range(1, len(playing)) if playing[i] < playing[i - 1]]
    assert all(playing[i] == T0 for i in jumps_back)  # each pass restarts at the recording's start
    assert 1 <= len(jumps_back) <= player.passes  # and time only moves forward within a pass


def test_bad_parameters_and_missing_files(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b.mcap")
    bus = MemoryBus()
    with pytest.raises(ParamError, match="rate"):
        Player(params={"file": str(bag), "rate": 0.0}, transport=bus.transport(), heartbeat_s=0)
    with pytest.raises(BagError, match="no such recording"):
        Player(params={"file": str(tmp_path / "nope.mcap")}, transport=bus.transport(), heartbeat_s=0)
    with pytest.raises(ParamError, match="file"):
        Player(params={}, transport=bus.transport(), heartbeat_s=0)


def test_timeline_publish_paces_by_the_publishers_stamps(tmp_path: Path) -> None:
    """A composed sim run is logged at CPU speed (here 1 ms apart) while its stamps are simulated time (10 ms
    apart): ``timeline: publish`` replays the simulated pace, ``log`` the recorder's."""
    msgs = [Rec("chatter", T0 + i * MS, _text(f"c{i}"), i + 1, publish_time=T0 + i * 10 * MS) for i in range(20)]
    bag = write_bag(tmp_path / "sim.mcap", msgs)
    spans = {}
    for timeline in ("publish", "log"):
        player, got = _play({"file": str(bag), "timeline": timeline})
        stamps = [r.header.stamp for r in got if r.topic == "chatter"]
        assert len(stamps) == 20
        spans[timeline] = ((stamps[-1] - stamps[0]) / MS, 3.0 + 1e3 * player.late_max_s)
    span, slack = spans["publish"]
    assert span == pytest.approx(190.0, abs=slack)
    span, slack = spans["log"]
    assert span == pytest.approx(19.0, abs=slack)


class _SlowConsumer(MemoryTransport):
    """A consumer slower than the replay: takes nothing in until the replay has ended, then one message a spin;
    ``lose`` messages on chatter never arrive (dropped at a high-water mark)."""

    def __init__(self, bus: MemoryBus, lose: set[int]) -> None:
        super().__init__(bus)
        self.go = False
        self.lose = lose
        self._chatter = 0

    def poll(self, timeout_s: float) -> list[Delivery]:
        while self.go and self.inbox:
            d = self.inbox.popleft()
            if d.frames[0] == b"chatter":
                self._chatter += 1
                if self._chatter in self.lose:
                    continue
            return [d]
        return []


def _play_to_slow_consumer(bag: Path, lose: set[int]) -> tuple[Player, Node]:
    """Play ``bag`` to a slow ``sink`` named in wait_for (the player spins it: one thread)."""
    bus = MemoryBus()
    slow = _SlowConsumer(bus, lose)
    bus._add(slow)
    sink = Node(name="sink", transport=slow, heartbeat_s=0.01)
    sink.subscribe("chatter", Text)

    class Paired(Player):
        def spin_once(self, timeout_s: float = 0.0) -> None:
            super().spin_once(0.0)
            slow.go = slow.go or self.played == 22  # every message of _bag played
            sink.spin_once(0.0)

    player = Paired(name="player", params={"file": str(bag), "exit_delay_s": 0.0, "drain_timeout_s": 0.5,
                                            "wait_for": ["sink"]}, transport=bus.transport(), heartbeat_s=0)
    try:
        player.spin()
    finally:
        player.close(0)
    return player, sink


def test_the_replay_ends_once_a_slow_consumer_took_everything_in(tmp_path: Path) -> None:
    player, sink = _play_to_slow_consumer(_bag(tmp_path / "b.mcap"), set())
    assert player.exit_code == 0
    assert sink.counters()["chatter"].received == 20  # when the player ended, not later
    sink.close(0)


def test_a_replay_that_lost_messages_downstream_does_not_end_clean(tmp_path: Path,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    player, sink = _play_to_slow_consumer(_bag(tmp_path / "b.mcap"), {3, 9, 17})
    assert player.exit_code == 1
    assert sink.counters()["chatter"].received == 17
    assert "sink took in 17 of the 20 messages played on chatter: 3 lost" in caplog.text
    sink.close(0)
