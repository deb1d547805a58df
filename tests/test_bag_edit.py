"""``palpa bag filter|cut|merge`` (issue 42): outputs the official ``mcap`` reader reads with the expected counts,
payloads, sequence numbers, schemas, blobs, metadata and the launch attachment kept, and a merged file replays."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from messages import Text
from palpa.cli.main import main
from palpa.net.wire import Header, encode_header
from palpa.record.format import LAUNCH_ATTACHMENT, MD_NODES, MD_RECORDING, META_SEQ_BASE
from palpa.record.reader import iter_bag, launch_text_of
from palpa.record.recorder import Recorder
from palpa.record.testing import Rec, check_official, play_in_memory, write_bag
from palpa.testing import NodeHarness

S = 1_000_000_000
LAUNCH = "# resolved\nnodes: []\n"


def _frames(topic: str, seq: int, text: str, *, node: str = "talker", latched: bool = False,
            blobs: tuple[bytes, ...] = ()) -> list[bytes]:
    header = encode_header(Header(type="Text", seq=seq, stamp=seq, node=node, latched=latched))
    return [topic.encode(), header, msgspec.msgpack.encode(Text(text=text, stamp_ns=seq)), *blobs]


def _text(text: str) -> bytes:
    return msgspec.msgpack.encode(Text(text=text, stamp_ns=1))


def _record(*paths: Path, count: int = 10, talker: str = "talker_{stem}") -> list[Path]:
    """Recordings made by Recorders (receive times from the wall clock), their messages published in turns: 'plan'
    latched, then ``count`` on 'chatter' (a blob on the first; text "<file stem> <i>"), then 'counter' once past
    2**32; the launch file attached. ``talker`` names chatter's publisher."""
    launch = paths[0].with_suffix(".yaml")
    launch.write_text(LAUNCH)
    hs = [NodeHarness(Recorder, {"output": str(p), "launch_file": str(launch)}) for p in paths]
    for h, p in zip(hs, paths, strict=True):
        h.publish_raw(_frames("plan", 1, f"{p.stem} plan", node="scanner", latched=True))
    for i in range(count):
        for h, p in zip(hs, paths, strict=True):
            h.publish_raw(_frames("chatter", i + 1, f"{p.stem} {i}", node=talker.format(stem=p.stem),
                                  blobs=(b"\x00blob",) if i == 0 else ()))
    for h, p in zip(hs, paths, strict=True):
        h.publish_raw(_frames("counter", 2**32 + 3, f"{p.stem} big", node="counter"))
        h.close()
    return list(paths)


def _texts(view_messages: list[tuple[str, int, int, int, bytes]], topic: str) -> list[str]:
    return [msgspec.msgpack.decode(m[4])["text"] for m in view_messages if m[0] == topic]


def test_filter_keeps_the_topics_asked_for_with_everything_that_describes_them(tmp_path: Path) -> None:
    (src,) = _record(tmp_path / "a.mcap")
    out = tmp_path / "f.mcap"
    assert main(["bag", "filter", str(src), "--topics", "chat.*", "counter", "-o", str(out)]) == 0
    view = check_official(out)
    original = check_official(src)
    assert [m for m in view.messages if not m[0].startswith("_palpa/blobs")] == \
        [m for m in original.messages if m[0] in ("chatter", "counter")]
    assert view.statistics.message_count == 10 + 1 + 1  # + the blob's companion message
    assert {c.topic for c in view.channels.values()} == {"chatter", "counter", "_palpa/blobs/chatter"}
    assert [c.metadata.get(META_SEQ_BASE) for c in view.channels.values() if c.topic == "counter"] == [str(2**32)]
    assert {s.name for s in view.schemas.values()} == {"Text", "palpa.Blobs"}
    assert view.attachments[LAUNCH_ATTACHMENT] == LAUNCH.encode() and launch_text_of(out) == LAUNCH
    assert view.metadata[MD_RECORDING] == original.metadata[MD_RECORDING] and MD_NODES in view.metadata
    assert view.metadata["palpa.edit"]["operation"] == "filter"
    assert {c.metadata["palpa.publisher"] for c in view.channels.values() if c.topic == "chatter"} == {"talker_a"}
    # palpa reads it back the same: blobs joined to their message, the full sequence number
    got = {(m.topic, m.seq): m.blobs for m in iter_bag([out])}
    assert got[("chatter", 1)] == (b"\x00blob",) and got[("chatter", 2)] == () and ("counter", 2**32 + 3) in got
    assert main(["bag", "filter", str(src), "--exclude", "chatter", "-o", str(tmp_path / "g.mcap")]) == 0
    assert {m[0] for m in check_official(tmp_path / "g.mcap").messages} == {"plan", "counter"}


def test_a_split_recording_becomes_one_file_with_its_latched_state_once(tmp_path: Path) -> None:
    plan = Rec("plan", 1 * S, _text("plan"), 1, node="scanner", latched=True)
    write_bag(tmp_path / "run-0001.mcap", [plan, *(Rec("chatter", (i + 2) * S, _text(f"c{i}"), i + 1)
                                                   for i in range(3))])
    # the second piece opens with the latched copy, as the recorder writes it
    write_bag(tmp_path / "run-0002.mcap", [Rec("plan", 5 * S, _text("plan"), 1, node="scanner", latched=True),
                                           *(Rec("chatter", (i + 2) * S, _text(f"c{i}"), i + 1)
                                             for i in range(3, 5))])
    out = tmp_path / "one.mcap"
    assert main(["bag", "filter", str(tmp_path / "run.mcap"), "--topics", "plan", "chatter", "-o", str(out)]) == 0
    view = check_official(out)
    assert [(m[0], m[1]) for m in view.messages] == [("plan", 1), *(("chatter", i) for i in range(1, 6))]


def test_cut_keeps_a_time_range_and_the_latched_state_before_it(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    first = 1_700_000_000 * S
    msgs = [Rec("plan", first, _text("a plan"), 1, node="scanner", latched=True)]
    msgs += [Rec("chatter", first + (i + 1) * S, _text(f"a {i}"), i + 1) for i in range(10)]
    src = write_bag(tmp_path / "a.mcap", msgs)
    out = tmp_path / "c.mcap"
    assert main(["bag", "cut", str(src), "--start", "3", "--end", "6", "-o", str(out)]) == 0
    assert "1 latched messages from before the start kept at the start" in capsys.readouterr().out
    view = check_official(out)
    assert _texts(view.messages, "chatter") == ["a 2", "a 3", "a 4", "a 5"]  # recorded at 3, 4, 5 and 6 s
    plan = [m for m in view.messages if m[0] == "plan"]
    assert len(plan) == 1 and plan[0][2] == first + 3 * S  # the scan plan, at the cut's start
    assert all(first + 3 * S <= m[2] <= first + 6 * S for m in view.messages)
    assert main(["bag", "cut", str(src), "--start", "30", "-o", str(tmp_path / "e.mcap")]) == 1
    assert "nothing written" in capsys.readouterr().err and not (tmp_path / "e.mcap").exists()
    assert main(["bag", "cut", str(src), "--start", "5", "--end", "2", "-o", str(tmp_path / "e.mcap")]) == 1
    assert "before its start" in capsys.readouterr().err


def test_merge_interleaves_recordings_by_time_and_the_result_replays(tmp_path: Path) -> None:
    a, b = _record(tmp_path / "a.mcap", tmp_path / "b.mcap", count=3)
    out = tmp_path / "m.mcap"
    assert main(["bag", "merge", str(a), str(b), "-o", str(out)]) == 0
    view = check_official(out)
    va, vb = check_official(a), check_official(b)
    assert view.statistics.message_count == va.statistics.message_count + vb.statistics.message_count
    assert va.statistics.message_count == 1 + 3 + 1 + 1  # plan, chatter, its blob, counter
    assert [m[2] for m in view.messages] == sorted(m[2] for m in va.messages + vb.messages)
    in_file = [(m.topic, msgspec.msgpack.decode(m.payload)["text"]) for m in iter_bag([out])]
    assert [t for topic, t in in_file if topic == "chatter"] == ["a 0", "b 0", "a 1", "b 1", "a 2", "b 2"]
    # each recording keeps its own channels (two talkers' sequence numbers each count from 1)
    assert len([c for c in view.channels.values() if c.topic == "chatter"]) == 2
    # every input's metadata but its drops, one palpa.drops recounted over the merge, and palpa.edit
    assert view.statistics.metadata_count == va.statistics.metadata_count + vb.statistics.metadata_count - 2 + 1 + 1

    player, got = play_in_memory({"file": str(out), "rate": 1000.0})
    assert player.exit_code == 0
    played = [msgspec.msgpack.decode(r.payload)["text"] for r in got if r.topic == "chatter"]
    assert played == ["a 0", "b 0", "a 1", "b 1", "a 2", "b 2"]
    assert [list(r.blobs) for r in got if r.topic == "chatter" and r.blobs] == [[b"\x00blob"]] * 2


def test_merge_keeps_one_copy_of_a_message_in_both_and_refuses_interleaved_streams_of_one_publisher(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b = _record(tmp_path / "a.mcap", tmp_path / "b.mcap", count=3, talker="talker")
    assert main(["bag", "merge", str(a), str(b), "-o", str(tmp_path / "m.mcap")]) == 1
    assert "chatter from 'talker' interleaves" in capsys.readouterr().err
    assert not (tmp_path / "m.mcap").exists()
    # two recorders of one bus hold the same messages: the merge holds each once
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(a.read_bytes())
    assert main(["bag", "merge", str(a), str(copy), "-o", str(tmp_path / "m.mcap")]) == 0
    assert "5 repeated copies dropped" in capsys.readouterr().out
    merged = [(m.topic, m.seq, m.payload) for m in iter_bag([tmp_path / "m.mcap"])]
    assert merged == [(m.topic, m.seq, m.payload) for m in iter_bag([a])]
    # one run after the other: a restart of the publisher, as it was live
    c, = _record(tmp_path / "c.mcap", count=2, talker="talker")
    assert main(["bag", "merge", str(a), str(c), "-o", str(tmp_path / "ac.mcap")]) == 0
    assert len(check_official(tmp_path / "ac.mcap").messages) == 6 + 5


def test_edit_errors_say_what_is_wrong_and_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (src,) = _record(tmp_path / "a.mcap", count=2)
    cases = [
        (["filter", str(src), "-o", str(tmp_path / "o.mcap")], "filter needs --topics or --exclude"),
        (["filter", str(src), "--topics", "nothing", "-o", str(tmp_path / "o.mcap")], "nothing written"),
        (["filter", str(src), "--topics", "(", "-o", str(tmp_path / "o.mcap")], "regex '(' is invalid"),
        (["cut", str(src), "-o", str(tmp_path / "o.mcap")], "cut needs --start or --end"),
        (["merge", str(src), "-o", str(tmp_path / "o.mcap")], "merge needs two recordings"),
        (["filter", str(src), "--topics", "chatter", "-o", str(src)], "is also an input"),
        (["filter", str(tmp_path / "none.mcap"), "--topics", "chatter", "-o", str(tmp_path / "o.mcap")],
         "no such recording"),
    ]
    for argv, text in cases:
        assert main(["bag", *argv]) == 1, argv
        assert text in capsys.readouterr().err, argv
    assert not (tmp_path / "o.mcap").exists()
    damaged = tmp_path / "d.mcap"
    damaged.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    assert main(["bag", "filter", str(damaged), "--topics", "chatter", "-o", str(tmp_path / "o.mcap")]) == 1
    assert "bag recover" in capsys.readouterr().err and not (tmp_path / "o.mcap").exists()


def test_a_recording_cut_anywhere_is_refused_with_a_message_not_a_traceback(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """A damaged input (a recorder killed mid-write) is refused wherever it was cut: within a record's length field
    too, which the official reader reports as a bare struct.error (seen as a flaky half-file cut above)."""
    (src,) = _record(tmp_path / "a.mcap", count=2)
    data = src.read_bytes()
    out = tmp_path / "o.mcap"
    for cut in range(8, len(data), max(1, len(data) // 60)):
        damaged = tmp_path / "d.mcap"
        damaged.write_bytes(data[:cut])
        assert main(["bag", "filter", str(damaged), "--topics", "chatter", "-o", str(out)]) == 1, cut
        assert "palpa bag recover" in capsys.readouterr().err or not out.exists(), cut
        assert not out.exists(), cut


def test_an_edited_recording_counts_the_gaps_of_what_it_kept(tmp_path: Path) -> None:
    """``palpa.drops`` of a cut or filtered file is recounted from the messages written (as ``recover`` does): the
    input's counts were of every topic over the whole run; a held latched copy from before the start is no gap."""
    import json

    first = 1_700_000_000 * S
    msgs = [Rec("plan", first, _text("a plan"), 1, node="scanner", latched=True)]
    msgs += [Rec("chatter", first + (i + 1) * S, _text(f"a {i}"), i + 1) for i in range(10) if i != 1]  # seq 2 lost
    msgs += [Rec("plan", first + 8 * S, _text("b plan"), 5, node="scanner", latched=True)]  # seqs 2-4 never recorded
    src = write_bag(tmp_path / "a.mcap", msgs)

    def gaps(path: Path) -> dict[str, int]:
        return {t: json.loads(d)["gaps"] for t, d in check_official(path).metadata["palpa.drops"].items()}

    assert main(["bag", "filter", str(src), "--exclude", "none", "-o", str(tmp_path / "all.mcap")]) == 0
    assert gaps(tmp_path / "all.mcap") == {"chatter": 1, "plan": 3}
    assert main(["bag", "filter", str(src), "--topics", "chatter", "-o", str(tmp_path / "f.mcap")]) == 0
    assert gaps(tmp_path / "f.mcap") == {"chatter": 1}
    assert main(["bag", "cut", str(src), "--start", "3", "--end", "7", "-o", str(tmp_path / "c.mcap")]) == 0
    assert gaps(tmp_path / "c.mcap") == {"chatter": 0}  # the held plan (seq 1) opens the range: not a gap of it
