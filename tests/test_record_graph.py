"""Record and replay with real processes on a real bus: a 1 kHz replay never early, a byte-identical round trip
(record, play, record again), and a bag from one graph replayed into a fresh graph reproducing the downstream
node's output (nodes.demo Talker -> Listener)."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from messages import Text
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.node.node import Node, RawMessage
from palpa.record.reader import iter_bag
from palpa.record.testing import Rec, check_official, write_bag
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from tests.procs import ProcessGroup, palpa_cmd, short_ipc_base, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

MS = 1_000_000


class Graph:
    """A bus, its processes and a watcher node that sees heartbeats; everything stopped in close()."""

    def __init__(self) -> None:
        self.bus = Bus(BusAddress.parse(f"ipc://{short_ipc_base()}"))
        self.address = self.bus.start()
        self.procs = ProcessGroup()
        self.env = {**__import__("os").environ, "PALPA_BUS": str(self.address), "PYTHONUNBUFFERED": "1"}
        self.watch = Node(name="watch", bus=self.address, heartbeat_s=0)
        self.beats: dict[str, Heartbeat] = {}
        self.watch.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda hb: self.beats.__setitem__(hb.node, hb))

    def start(self, *args: str):  # type: ignore[no-untyped-def]
        return self.procs.start(palpa_cmd(*args), env=self.env)

    def wait_for(self, cond, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
        wait_until(cond, timeout, what, step=lambda: self.watch.spin_once(0.05))

    def wait_nodes(self, *names: str) -> None:
        self.wait_for(lambda: all(n in self.beats for n in names), 20, f"heartbeats of {names}")

    def received(self, node: str, topic: str) -> int:
        hb = self.beats.get(node)
        c = hb.counters.get(topic) if hb is not None else None
        return c.received if c is not None else 0

    def close(self) -> None:
        try:
            self.watch.close(0)
            self.procs.cleanup()
        finally:
            self.bus.stop()


@pytest.fixture
def graph() -> Iterator[Graph]:
    g = Graph()
    try:
        yield g
    finally:
        g.close()


@pytest.fixture(scope="module")
def talker_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Graph 1: Talker -> Listener, everything recorded (chatter and the listener's chatter_len)."""
    bag = tmp_path_factory.mktemp("graph1") / "graph1.mcap"
    g = Graph()
    try:
        rec = g.start("record", "-o", str(bag), "chatter", "chatter_len")
        listener = g.start("run", "nodes.demo:Listener")
        g.wait_nodes("recorder", "listener")
        talker = g.start("run", "nodes.demo:Talker", "-p", "rate_hz=100", "-p", "count=120")
        assert talker.wait(30) == 0
        g.wait_for(lambda: g.received("recorder", "chatter") > 100
                   and g.received("recorder", "chatter_len") == g.received("recorder", "chatter"),
                   10, "the recorder to see every chatter_len")
        assert rec.stop(10) == 0, rec.output()
        assert listener.stop(10) == 0
    finally:
        g.close()
    check_official(bag)
    return bag


def _stream(bag: Path, topic: str) -> list[tuple[str, int, str, bytes]]:
    return [(m.node, m.seq, m.type, m.payload) for m in iter_bag([bag]) if m.topic == topic]


def test_replay_at_1khz_is_complete_in_order_and_never_early(graph: Graph, tmp_path: Path) -> None:
    """Every message of a 1 kHz recording, in order, none sent before its schedule (a player that bursts or runs
    fast fails). How late it sends under load is a wall-clock figure: bench/replay.py measures it."""
    n, t0 = 1500, 1_700_000_000_000_000_000
    payload = msgspec.msgpack.encode(Text(text="imu sample", stamp_ns=0))
    bag = write_bag(tmp_path / "khz.mcap", [Rec("imu", t0 + i * MS, payload, i + 1) for i in range(n)])
    got: list[RawMessage] = []
    graph.watch.subscribe_raw("imu", got.append)
    player = graph.start("play", str(bag))
    graph.wait_for(lambda: len(got) >= n or player.popen.poll() is not None, 60, "the replay")
    assert player.wait(10) == 0, player.output()
    graph.wait_for(lambda: len(got) >= n, 5, "every message")
    assert [r.header.seq for r in got] == list(range(1, n + 1))
    # each send time relative to the first one, against the schedule relative to the first: lateness varies with
    # load; earliness can only be the first message's own lateness (the player's time base is set just before
    # it), allowed up to 50 ms, far below what a player that runs fast or sends in bursts gets wrong (seconds)
    first = got[0].header.stamp
    early = [(i, (i * MS) - (r.header.stamp - first)) for i, r in enumerate(got)]
    worst = max(early, key=lambda e: e[1])
    assert worst[1] <= 50 * MS, f"message {worst[0] + 1} sent {worst[1] / MS:.3f} ms before its schedule"


def test_round_trip_is_byte_identical(graph: Graph, talker_bag: Path, tmp_path: Path) -> None:
    bag2 = tmp_path / "again.mcap"
    rec = graph.start("record", "-o", str(bag2), "chatter")
    graph.wait_nodes("recorder")
    player = graph.start("play", str(talker_bag), "--topics", "chatter")
    assert player.wait(30) == 0, player.output()
    assert rec.stop(10) == 0, rec.output()
    check_official(bag2)
    first, again = _stream(talker_bag, "chatter"), _stream(bag2, "chatter")
    assert len(first) > 100
    assert again == first  # same publisher, sequence numbers, type and payload bytes


def test_replayed_bag_reproduces_downstream_output(graph: Graph, talker_bag: Path, tmp_path: Path) -> None:
    expected = _stream(talker_bag, "chatter_len")
    assert [s for _, s, _, _ in expected] == list(range(1, len(expected) + 1))  # graph 1 lost nothing
    bag3 = tmp_path / "downstream.mcap"
    rec = graph.start("record", "-o", str(bag3), "chatter_len")
    listener = graph.start("run", "nodes.demo:Listener")
    graph.wait_nodes("recorder", "listener")
    player = graph.start("play", str(talker_bag), "--topics", "chatter", "--rate", "2")
    assert player.wait(30) == 0, player.output()
    graph.wait_for(lambda: graph.received("recorder", "chatter_len") >= len(expected), 10,
                   "the listener's output to be recorded")
    listener.signal(signal.SIGINT)
    assert rec.stop(10) == 0, rec.output()
    check_official(bag3)
    assert _stream(bag3, "chatter_len") == expected


REPLAY_LAUNCH = """\
description: replay chatter from a recording while the listener runs live (docs/recording.md)
args:
  - {name: bag, description: the recording to replay}
record: {topics: [chatter_len]}
nodes:
  - name: listener
    node: nodes.demo:Listener
    env: {PALPA_SIM_CLOCK: "1"}        # follows the replay clock (and waits for its first tick)
  - name: replay
    node: palpa.record.player:Player
    params: {file: $(arg bag), topics: [chatter], wait_for: [listener], clock: true}
    required: true
"""


def test_launch_file_replaces_a_live_source(talker_bag: Path, tmp_path: Path) -> None:
    """The documented recipe: a Player node in a launch file instead of the talker, driving the clock of a
    sim-clock listener; the live listener's output (recorded by the launch's record section) is the one of the
    original run."""
    launch = tmp_path / "replay.yaml"
    launch.write_text(REPLAY_LAUNCH)
    procs = ProcessGroup()
    try:
        run = procs.start(palpa_cmd("launch", str(launch), f"bag:={talker_bag}", "--run-dir", str(tmp_path / "run")))
        assert run.wait(60) == 0, run.output()
        assert "not ready" not in run.output()  # the player heard the sim-clock listener start
    finally:
        procs.cleanup()
    recording = tmp_path / "run" / "recording.mcap"
    assert check_official(recording).attachments["launch.resolved.yaml"]  # the launcher's record section
    assert _stream(recording, "chatter_len") == _stream(talker_bag, "chatter_len")
