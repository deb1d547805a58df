"""The recorder at its limits (issue 39): every message is recorded with a true index or refused and counted, and
the recorder stays up — out-of-range stamps, more channels than MCAP holds, latched values and publisher state
past their bounds. Files are read back with the official ``mcap`` reader (palpa.record.testing.check_official)."""

from __future__ import annotations

import base64
import json
import logging
from pathlib import Path

import msgspec
import pytest
from mcap.reader import make_reader

from messages import Text
from palpa.cli.main import main
from palpa.net.wire import MAX_NESTING, Header, SequenceTracker, TopicStats, encode_header
from palpa.record.format import MD_REFUSED, BagError
from palpa.record.recorder import MAX_LATCHED_BYTES, RESERVED_CHANNELS, Recorder
from palpa.record.testing import Rec, check_official, write_bag
from palpa.record.writer import MAX_CHANNELS, BagWriter
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from palpa.testing import NodeHarness

TEXT = msgspec.msgpack.encode(Text(text="hi"))


def frames(seq: int, stamp: int = 1, node: str = "ext", topic: str = "chatter", latched: bool = False,
           payload: bytes = TEXT, blobs: tuple[bytes, ...] = ()) -> list[bytes]:
    """A message's frames as any client may send them: a hostile one encodes a negative stamp as a plain msgpack
    int (palpa's own encode_header writes uint64 only and refuses it)."""
    if stamp >= 0:
        header = encode_header(Header(type="Text", seq=seq, stamp=stamp, node=node, latched=latched))
    else:
        fields = {"type": "Text", "seq": seq, "stamp": stamp, "node": node, **({"latched": True} if latched else {})}
        header = msgspec.msgpack.encode(fields)
    return [topic.encode(), header, payload, *blobs]


def test_writer_refuses_a_time_out_of_range_and_keeps_its_index_true(tmp_path: Path) -> None:
    w = BagWriter(tmp_path / "w.mcap")
    cid = w.register_channel("t", "msgpack", 0, {})
    w.add_message(cid, 1, 1, 1, b"a")
    for log_time, publish_time, seq in ((1, -1, 2), (-5, 1, 2), (1, 1, 2**32), (1, 2**64, 2)):
        with pytest.raises(BagError, match="out of range"):
            w.add_message(cid, log_time, publish_time, seq, b"bad")
    w.add_message(cid, 2, 2, 2, b"b")
    w.finish()
    view = check_official(tmp_path / "w.mcap")
    assert [m[4] for m in view.messages] == [b"a", b"b"]


def test_negative_stamps_are_refused_and_counted_and_the_index_stays_true(tmp_path: Path,
                                                                          caplog: pytest.LogCaptureFixture) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    for seq in range(1, 11):
        h.publish_raw(frames(seq, stamp=-seq if seq in (3, 4, 9) else 1_000 + seq))
    h.close()
    view = check_official(out)  # statistics == messages read, indexed and streamed alike
    assert [m[1] for m in view.messages if m[0] == "chatter"] == [1, 2, 5, 6, 7, 8, 10]
    assert view.metadata[MD_REFUSED] == {"stamp_out_of_range": "3"}
    assert h.node.refused == {"stamp_out_of_range": 3}
    assert "stamp -3 ns is before 1970" in caplog.text and "REFUSED 3 stamp out of range" in h.node.report()


def flood_channels(tmp_path: Path, caplog: pytest.LogCaptureFixture, limit: int) -> None:
    """More sequence epochs (one channel each) than the recorder takes, then a graph node's messages."""
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    caplog.set_level(logging.WARNING)
    n = limit + 100
    for k in range(n):  # every sequence epoch (seq >> 32) is a channel of its own
        h.publish_raw(frames((k << 32) | 1, stamp=k + 1, node="flood"))
    flood_kept = limit - RESERVED_CHANNELS - 1  # one slot always kept for a blob channel
    h.publish(HEARTBEAT_TOPIC, Heartbeat(node="graph", pid=1, host="h", publishes={}, subscribes={}, counters={},
                                         sent={}, uptime_s=1.0))  # a graph node announces itself: reserved room
    for seq in range(1, 4):
        h.publish_raw(frames(seq, stamp=seq, node="graph", topic="graph/state"))
    assert not h.node._failed
    h.close()
    view = check_official(out)
    assert sum(1 for m in view.messages if m[0] == "chatter") == flood_kept
    assert [m[1] for m in view.messages if m[0] == "graph/state"] == [1, 2, 3]
    # the flood's refusals, and the recorder's own log lines about them (it sends no heartbeat in a harness)
    refused = h.node.refused["channel_limit"]
    assert refused >= n - flood_kept and view.metadata[MD_REFUSED] == {"channel_limit": str(refused)}
    lines = [r for r in caplog.records if "channels, the most it takes" in r.getMessage()]
    assert len(lines) == 1  # throttled: one line, every refusal counted


def test_channels_past_the_limit_are_refused_and_the_recorder_stays_up(tmp_path: Path,
                                                                       caplog: pytest.LogCaptureFixture,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("palpa.record.recorder.MAX_CHANNELS", RESERVED_CHANNELS + 500)
    flood_channels(tmp_path, caplog, RESERVED_CHANNELS + 500)


@pytest.mark.slow
def test_channels_past_the_mcap_limit_are_refused_and_the_recorder_stays_up(tmp_path: Path,
                                                                            caplog: pytest.LogCaptureFixture) -> None:
    flood_channels(tmp_path, caplog, MAX_CHANNELS)  # about 20 s: the mcap library writes 65535 Channel records


def test_latched_values_the_recorder_keeps_are_bounded_in_bytes(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    big = msgspec.msgpack.encode(Text(text="x" * (MAX_LATCHED_BYTES // 6)))
    for i in range(8):
        h.publish_raw(frames(1, stamp=1, node=f"pub{i}", topic=f"cal/{i}", latched=True, payload=big))
    rec = h.node
    assert rec._latched.bytes <= MAX_LATCHED_BYTES
    assert [k[0] for k in rec._latched] == ["cal/3", "cal/4", "cal/5", "cal/6", "cal/7"]  # oldest went first
    assert rec.refused == {"latched_forgotten": 3}
    h.close()
    assert sum(1 for m in check_official(out).messages if m[0].startswith("cal/")) == 8  # all recorded


def test_sequence_state_is_bounded_and_forgets_the_least_recently_heard() -> None:
    tracker = SequenceTracker(max_entries=3)
    stats = TopicStats()
    for node in ("a", "b", "c"):
        tracker.observe("t", node, 1, stats)
    tracker.observe("t", "a", 2, stats)  # a is now the most recently heard
    tracker.observe("t", "d", 1, stats)  # forgets b
    assert len(tracker) == 3 and tracker.forgotten == 1
    assert tracker.seen_at_least("t", "a", 2) and not tracker.seen_at_least("t", "b", 1)
    assert tracker.observe_run("t", "e", 1, 5, stats)  # a batch from a new name also makes room
    assert len(tracker) == 3 and tracker.forgotten == 2 and not tracker.seen_at_least("t", "c", 1)
    assert not tracker.observe("t", "a", 2, stats) and stats.duplicates == 1  # a duplicate keeps its entry
    assert tracker.seen_at_least("t", "a", 2)


def test_recover_in_place_refuses_a_file_a_recorder_is_writing(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "live.mcap"
    w = BagWriter(path)  # a live recorder's writer: it holds the file's lock while it writes
    cid = w.register_channel("t", "msgpack", 0, {})
    for i in range(1, 6):
        w.add_message(cid, i, i, i, b"x")
    w.flush()
    before = path.read_bytes()
    assert main(["bag", "recover", "--in-place", str(path)]) == 1
    assert "is in use: a recorder is still writing it" in capsys.readouterr().err
    assert path.read_bytes() == before and not (tmp_path / "live.mcap.partial").exists()
    assert main(["bag", "recover", str(path), "-o", str(tmp_path / "copy.mcap")]) == 0  # a snapshot is allowed
    assert "still being written" in capsys.readouterr().err
    for i in range(6, 11):  # the recorder goes on, undisturbed
        w.add_message(cid, i, i, i, b"x")
    w.finish()
    assert [m[1] for m in check_official(path).messages] == list(range(1, 11))
    w2 = BagWriter(tmp_path / "dead.mcap")
    w2.add_message(w2.register_channel("t", "msgpack", 0, {}), 1, 1, 1, b"x")
    w2.abandon()  # its writer died: the lock went with it
    assert main(["bag", "recover", "--in-place", str(tmp_path / "dead.mcap")]) == 0
    assert len(check_official(tmp_path / "dead.mcap").messages) == 1


def test_export_json_writes_a_placeholder_for_a_deeply_nested_payload_and_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    deep = b"\x81\xa4text" + b"\x91" * 5000 + b"\x01"
    payloads = [TEXT, deep, TEXT, b"\x81\xa4text" + b"\x91" * MAX_NESTING + b"\x01"]
    bag = write_bag(tmp_path / "in.mcap", [Rec("chatter", 10 + i, p, i + 1) for i, p in enumerate(payloads)])
    out = tmp_path / "out.mcap"
    assert main(["bag", "export", str(bag), "--json", str(out)]) == 1
    captured = capsys.readouterr()
    assert "2 message(s) exported as placeholders" in captured.out and "#1 on 'chatter' (nested deeper" in captured.out
    assert "#3 on 'chatter'" in captured.out and "exit status 1" in captured.err
    with open(out, "rb") as fh:
        exported = [json.loads(m.data) for _s, _c, m in make_reader(fh).iter_messages()]
    assert exported[0] == exported[2] == {"text": "hi", "stamp_ns": 0}
    for index in (1, 3):
        assert exported[index]["_palpa_index"] == index
        assert f"nested deeper than {MAX_NESTING} levels" in exported[index]["_palpa_error"]
        assert base64.b64decode(exported[index]["_palpa_msgpack_base64"]) == payloads[index]


def test_a_payload_that_is_not_utf8_is_recorded_and_counted_as_malformed(tmp_path: Path,
                                                                         caplog: pytest.LogCaptureFixture) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    h.publish_raw(frames(1, payload=b"\x81\xa4text\xa1\x80"))
    h.publish_raw(frames(2))
    assert h.node.counters()["chatter"].decode_errors == 1
    h.close()
    assert [m[1] for m in check_official(out).messages if m[0] == "chatter"] == [1, 2]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]


def test_forgetting_publishers_is_counted_and_logged_once_per_interval(tmp_path: Path,
                                                                      caplog: pytest.LogCaptureFixture) -> None:
    h = NodeHarness(Recorder, {"output": str(tmp_path / "r.mcap")})
    h.node._rx._raw_tracker.max_entries = 10  # MAX_TRACKED_PUBLISHERS, made small
    caplog.set_level(logging.WARNING)
    for i in range(15):
        h.publish_raw(frames(1, node=f"name-{i}"))
    tracker = h.node._rx._raw_tracker  # (its own log line about it is one more pair)
    assert h.node._rx.publishers_forgotten >= 5 and len(tracker) == 10
    assert tracker.seen_at_least("chatter", "name-14", 1) and not tracker.seen_at_least("chatter", "name-4", 1)
    lines = [r.getMessage() for r in caplog.records if "sequence state full" in r.getMessage()]
    assert len(lines) == 1 and "forgot 'name-0' on 'chatter'" in lines[0]
    h.close()


def _live_writer(path: Path) -> tuple[BagWriter, bytes]:
    """A live recorder's writer on ``path`` with a few flushed messages, and the file's bytes as they stand."""
    w = BagWriter(path)
    cid = w.register_channel("t", "msgpack", 0, {})
    for i in range(1, 6):
        w.add_message(cid, i, i, i, b"x" * 100)
    w.flush()
    return w, path.read_bytes()


def test_force_refuses_a_file_a_live_recorder_holds_without_touching_a_byte(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    w, before = _live_writer(path)
    with pytest.raises(BagError, match="is in use"):
        BagWriter(path, overwrite=True)
    with pytest.raises(BagError, match="is in use"):  # the recorder node, as `palpa record --force` runs it
        NodeHarness(Recorder, {"output": str(path), "force": True})
    assert path.read_bytes() == before
    w.finish()
    assert [m[1] for m in check_official(path).messages] == [1, 2, 3, 4, 5]
    again = BagWriter(path, overwrite=True)  # its recorder is gone: --force overwrites, as it says
    again.finish()
    assert check_official(path).messages == []


def test_force_deletes_no_piece_of_a_split_recording_a_live_recorder_holds(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    (tmp_path / "run-0001.mcap").write_bytes(b"an earlier run's first piece, its recorder gone")
    w, before = _live_writer(tmp_path / "run-0002.mcap")
    with pytest.raises(BagError, match="run-0002.mcap is in use"):
        NodeHarness(Recorder, {"output": str(out), "force": True, "split_size_mb": 1.0})
    assert (tmp_path / "run-0001.mcap").exists() and (tmp_path / "run-0002.mcap").read_bytes() == before
    w.finish()
    h = NodeHarness(Recorder, {"output": str(out), "force": True, "split_size_mb": 1.0})  # nobody holds them now
    h.close()
    assert [p.name for p in sorted(tmp_path.iterdir())] == ["run-0001.mcap"]
