"""The Recorder node on the in-memory bus: what it writes, per publisher and per type; filters; splits;
drops; blobs; node list; parameter and file errors. Every file is checked with the official mcap reader."""

from __future__ import annotations

import json
from pathlib import Path

import msgspec
import pytest

from messages import Text
from palpa.errors import ParamError
from palpa.message import json_schema
from palpa.net.wire import Header, encode_header
from palpa.node.node import Node
from palpa.record.format import (
    LAUNCH_ATTACHMENT,
    MD_DROPS,
    MD_NODES,
    MD_RECORDING,
    META_PUBLISHER,
    META_SCHEMA,
    META_SEQ_BASE,
    BagError,
)
from palpa.record.reader import iter_bag, resolve_bag_paths
from palpa.record.recorder import Recorder
from palpa.record.testing import check_official
from palpa.runtime_msgs import HEARTBEAT_TOPIC, LOG_TOPIC, Heartbeat, LogRecord
from palpa.testing import NodeHarness


def _frames(topic: str, type_name: str, seq: int, payload: bytes, node: str = "ext", latched: bool = False,
            blobs: tuple[bytes, ...] = ()) -> list[bytes]:
    header = encode_header(Header(type=type_name, seq=seq, stamp=1_000 + seq, node=node, latched=latched))
    return [topic.encode(), header, payload, *blobs]


def test_records_wire_payloads_byte_for_byte(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    for i in range(20):
        h.publish("chatter", Text(text=f"hello {i}", stamp_ns=i))
    on_bus = [(r.header.seq, r.header.stamp, r.payload) for r in h.raw if r.topic == "chatter"]
    h.close()
    view = check_official(out)
    assert [(m[1], m[3], m[4]) for m in view.messages if m[0] == "chatter"] == on_bus
    assert json.loads(view.schemas[1].data) == json_schema(Text)
    assert view.schemas[1].name == "Text" and view.channels[1].metadata[META_PUBLISHER] == "harness"
    rec = view.metadata[MD_RECORDING]
    assert rec["palpa_version"] and rec["recorder"] == "recorder" and json.loads(rec["params"])["output"] == str(out)
    assert json.loads(view.metadata[MD_DROPS]["chatter"])["gaps"] == 0


def test_one_channel_per_publisher_and_type(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    other = Node(name="other", transport=h.bus.transport(), clock=h.clock, heartbeat_s=0)
    try:
        pub = other.publisher("chatter", Text)
        for i in range(3):
            h.publish("chatter", Text(text=f"a{i}"))
            pub.publish(Text(text=f"b{i}"))
            h.spin()
        h.publish_raw(_frames("chatter", "Mystery", 1, msgspec.msgpack.encode({"x": 1})))
    finally:
        other.close(0)
        h.close()
    view = check_official(out)
    pubs = sorted((c.topic, c.metadata[META_PUBLISHER], c.metadata["palpa.type"]) for c in view.channels.values()
                  if c.topic == "chatter")
    assert pubs == [("chatter", "ext", "Mystery"), ("chatter", "harness", "Text"), ("chatter", "other", "Text")]
    mystery = next(c for c in view.channels.values() if c.metadata["palpa.type"] == "Mystery")
    assert mystery.schema_id == 0 and "not importable" in mystery.metadata[META_SCHEMA]
    got = {(m.node, m.seq) for m in iter_bag([out]) if m.topic == "chatter"}
    assert got == {("harness", 1), ("harness", 2), ("harness", 3), ("other", 1), ("other", 2), ("other", 3),
                   ("ext", 1)}


def test_topic_filters_and_runtime_topics(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out), "topics": ["probe/.*", "chatter"], "exclude": ["probe/raw"]})
    for topic in ("probe/heights", "probe/raw", "chatter", "chatter2", "other"):
        h.publish(topic, Text(text=topic))
    h.publish(LOG_TOPIC, LogRecord(node="x", level="INFO", text="kept", stamp_ns=1))
    h.publish(HEARTBEAT_TOPIC, Heartbeat(node="x", pid=1, host="h", publishes={}, subscribes={}, counters={},
                                         sent={}, uptime_s=1.0))
    h.close()
    topics = {m[0] for m in check_official(out).messages}
    assert topics == {"probe/heights", "chatter", LOG_TOPIC}

    out2 = tmp_path / "r2.mcap"
    h = NodeHarness(Recorder, {"output": str(out2), "topics": ["_palpa/heartbeat"], "exclude": ["_palpa/log"]})
    h.publish(LOG_TOPIC, LogRecord(node="x", level="INFO", text="dropped", stamp_ns=1))
    h.publish(HEARTBEAT_TOPIC, Heartbeat(node="x", pid=1, host="h", publishes={}, subscribes={}, counters={},
                                         sent={}, uptime_s=1.0))
    h.publish("chatter", Text(text="not asked for"))
    h.close()
    assert {m[0] for m in check_official(out2).messages} == {HEARTBEAT_TOPIC}


def test_node_list_from_heartbeats_and_launch_attachment(tmp_path: Path) -> None:
    launch = tmp_path / "launch.resolved.yaml"
    launch.write_text("nodes:\n  - name: talker\n")
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out), "launch_file": str(launch)})
    h.publish(HEARTBEAT_TOPIC, Heartbeat(node="talker", pid=42, host="rig", publishes={"chatter": "Text"},
                                         subscribes={}, counters={}, sent={"chatter": 3}, uptime_s=2.0))
    h.advance(0.6)  # the flush timer writes the changed node list right away (survives a SIGKILL)
    h.close()
    view = check_official(out)
    talker = json.loads(view.metadata[MD_NODES]["talker"])
    assert talker == {"pid": 42, "host": "rig", "publishes": {"chatter": "Text"}, "subscribes": {}}
    assert view.attachments[LAUNCH_ATTACHMENT] == launch.read_bytes()


def test_drops_are_counted_from_sequence_gaps(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    payload = msgspec.msgpack.encode({"text": "x", "stamp_ns": 0})
    for seq in (1, 2, 3, 7, 8, 20):
        h.publish_raw(_frames("chatter", "Text", seq, payload))
    h.close()
    assert "DROPS chatter: 14 missing" in h.node.report()  # 4-6 and 9-19
    h2 = NodeHarness(Recorder, {"output": str(tmp_path / "r2.mcap")})
    for seq in (1, 2, 1, 2):  # the publisher restarted: not a drop
        h2.publish_raw(_frames("chatter", "Text", seq, payload))
    h2.close()
    assert h2.node.report().endswith("no drops (no sequence gaps); also chatter: 1 restarts")
    assert json.loads(check_official(out).metadata[MD_DROPS]["chatter"])["gaps"] == 14


def test_split_pieces_stand_alone(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    h = NodeHarness(Recorder, {"output": str(out), "split_size_mb": 0.001})
    h.publish("calibration", Text(text="latched cal"), latched=True)
    n = 0
    for _ in range(4):
        for _ in range(30):
            n += 1
            h.publish("chatter", Text(text=f"message number {n:04d} " + "x" * 40))
        h.advance(0.5)  # the flush closes the chunk; past the size the next piece starts
    h.close()
    pieces = resolve_bag_paths(out)
    assert not out.exists() and [p.name for p in pieces] == [f"run-{i:04d}.mcap" for i in range(1, len(pieces) + 1)]
    assert len(pieces) >= 3
    seen: list[bytes] = []
    for i, piece in enumerate(pieces, start=1):
        view = check_official(piece)
        assert {s.name for s in view.schemas.values()} == {"Text"}
        assert view.messages[0][0] == "calibration"  # the latched value opens every piece
        assert msgspec.msgpack.decode(view.messages[0][4])["text"] == "latched cal"
        assert view.metadata[MD_RECORDING]["file_index"] == str(i)
        assert MD_DROPS in view.metadata
        seen += view.topic("chatter")
    texts = [msgspec.msgpack.decode(p)["text"] for p in seen]
    assert texts == [f"message number {k:04d} " + "x" * 40 for k in range(1, n + 1)]  # nothing lost or doubled
    # the copies that open later pieces keep the original identity, so the player can skip them
    copies = [m for m in iter_bag(pieces) if m.topic == "calibration"]
    assert len(copies) == len(pieces) and {(m.node, m.seq, m.latched) for m in copies} == {("harness", 1, True)}


def test_split_by_duration(tmp_path: Path) -> None:
    out = tmp_path / "d.mcap"
    h = NodeHarness(Recorder, {"output": str(out), "split_duration_s": 1.0})
    for _ in range(5):
        h.publish("chatter", Text(text="tick"))
        h.advance(0.5)
    h.close()
    pieces = resolve_bag_paths(out)
    assert len(pieces) == 3  # 2.5 s of mock time, a new piece every second
    assert sum(len(check_official(p).topic("chatter")) for p in pieces) == 5


def test_blobs_and_huge_sequence_numbers_round_trip(tmp_path: Path) -> None:
    out = tmp_path / "b.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    payload = msgspec.msgpack.encode({"text": "frame", "stamp_ns": 0})
    h.publish_raw(_frames("camera/debug", "Text", 1, payload, blobs=(b"\x00\xff" * 100, b"png")))
    h.publish_raw(_frames("camera/debug", "Text", 2, payload))
    big = 2**32 + 5
    h.publish_raw(_frames("counter", "Text", big, payload))
    h.close()
    view = check_official(out)
    assert any(c.topic == "_palpa/blobs/camera/debug" for c in view.channels.values())
    assert [c.metadata.get(META_SEQ_BASE) for c in view.channels.values() if c.topic == "counter"] == [str(2**32)]
    got = {(m.topic, m.seq): m.blobs for m in iter_bag([out])}
    assert got == {("camera/debug", 1): (b"\x00\xff" * 100, b"png"), ("camera/debug", 2): (), ("counter", big): ()}


def test_file_and_parameter_errors(tmp_path: Path) -> None:
    existing = tmp_path / "e.mcap"
    existing.write_bytes(b"old run")
    with pytest.raises(BagError, match="already exists"):
        NodeHarness(Recorder, {"output": str(existing)})
    assert existing.read_bytes() == b"old run"
    NodeHarness(Recorder, {"output": str(existing), "force": True}).close()
    check_official(existing)
    with pytest.raises(BagError, match="does not exist"):
        NodeHarness(Recorder, {"output": str(tmp_path / "no" / "dir.mcap")})
    (tmp_path / "s-0002.mcap").write_bytes(b"stale")
    with pytest.raises(BagError, match="s-0002.mcap already exists"):
        NodeHarness(Recorder, {"output": str(tmp_path / "s.mcap"), "split_size_mb": 1})
    with pytest.raises(ParamError, match="flush_period_s"):
        NodeHarness(Recorder, {"output": str(tmp_path / "f.mcap"), "flush_period_s": 2.0})
    with pytest.raises(ParamError, match="compression"):
        NodeHarness(Recorder, {"output": str(tmp_path / "f.mcap"), "compression": "gzip"})
    with pytest.raises(BagError, match="regex"):
        NodeHarness(Recorder, {"output": str(tmp_path / "f.mcap"), "topics": ["("]})
