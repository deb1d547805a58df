"""``palpa bag info|recover|export`` and the error paths of ``palpa record`` / ``palpa play``, run in-process."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import msgspec
import pytest

import palpa
from messages import Text
from palpa.cli.main import main
from palpa.record.format import MD_NODES, MD_RECORDING
from palpa.record.recorder import Recorder
from palpa.record.testing import Rec, check_official, write_bag
from palpa.testing import NodeHarness

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


class CliBlob(palpa.Message, frozen=True, kw_only=True):
    """A message with a binary field (bytes travel as msgpack bin, and as base64 in JSON)."""

    name: str
    data: bytes
    values: list[float] = []


def _bag(tmp_path: Path) -> Path:
    msgs = [Rec("chatter", T0 + i * 10 * MS, msgspec.msgpack.encode(Text(text=f"hi {i}")), seq)
            for i, seq in enumerate([1, 2, 3, 6, 7, 8, 9, 10, 11, 12])]  # 4 and 5 were dropped
    msgs += [Rec("probe/raw", T0 + i * 20 * MS, msgspec.msgpack.encode(
        CliBlob(name="b", data=b"\x00\x01\xfe", values=[1.5, float("nan")])), i + 1, type="CliBlob",
        node="probe") for i in range(5)]
    msgs += [Rec("mystery", T0 + 5 * MS, msgspec.msgpack.encode({"k": [1, 2]}), 1, type="NotImportable", node="x")]
    return write_bag(tmp_path / "cli.mcap", sorted(msgs, key=lambda m: m.log_time), metadata={
        MD_RECORDING: {"palpa_version": "0.1.0", "host": "rig", "recorder": "recorder"},
        MD_NODES: {"talker": json.dumps({"pid": 12, "host": "rig", "publishes": {"chatter": "Text"}})},
        "palpa.drops": {"chatter": json.dumps({"gaps": 2, "restarts": 0, "decode_errors": 0})},
    })


def test_bag_info_text_and_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = _bag(tmp_path)
    assert main(["bag", "info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "duration:    0.090 s" in out and "messages:    16" in out
    chatter = next(line for line in out.splitlines() if line.strip().startswith("chatter"))
    assert "Text" in chatter and "10 msgs" in chatter and "100.00 Hz" in chatter and "2 dropped" in chatter
    assert "drops:       2 messages missing" in out and "talker (pid 12 on rig)" in out
    assert main(["bag", "info", "--json", str(bag)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["topics"]["probe/raw"]["types"] == ["CliBlob"] and info["topics"]["probe/raw"]["messages"] == 5
    assert info["topics"]["mystery"]["schema"] is False
    assert info["files"][0]["finalized"] is True


def test_bag_info_on_an_unfinished_file_counts_gaps_itself(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "live.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    for seq in (1, 2, 5):
        h.publish_raw([b"chatter", msgspec.msgpack.encode({"type": "Text", "seq": seq, "stamp": 1, "node": "t"}),
                       msgspec.msgpack.encode(Text(text="x"))])
    h.advance(0.5)
    crashed = tmp_path / "crashed.mcap"
    shutil.copyfile(out, crashed)
    h.close()
    assert main(["bag", "info", str(crashed)]) == 0
    text = capsys.readouterr().out
    assert "NOT FINALIZED" in text and "2 dropped" in text
    assert main(["bag", "recover", str(crashed)]) == 0
    assert "recovered 3 messages" in capsys.readouterr().out
    check_official(tmp_path / "crashed.recovered.mcap")
    assert main(["bag", "recover", "--in-place", str(crashed)]) == 0
    capsys.readouterr()
    check_official(crashed)


def test_bag_export_json_reads_in_any_viewer(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = _bag(tmp_path)
    out = tmp_path / "cli.json.mcap"
    assert main(["bag", "export", str(bag), "--json", str(out)]) == 0
    assert "exported 16 messages" in capsys.readouterr().out
    view = check_official(out)
    assert {c.message_encoding for c in view.channels.values()} == {"json"}
    schemas = {s.name: json.loads(s.data) for s in view.schemas.values()}
    assert set(schemas) == {"Text", "CliBlob"}  # NotImportable has none: schemaless json
    for schema in schemas.values():
        assert schema["type"] == "object" and "$ref" not in json.dumps(schema)
    assert schemas["CliBlob"]["properties"]["data"]["contentEncoding"] == "base64"
    first = json.loads(view.topic("probe/raw")[0])
    assert first == {"name": "b", "data": "AAH+", "values": [1.5, None]}  # bytes as base64, NaN as null
    assert json.loads(view.topic("chatter")[0])["text"] == "hi 0"
    assert json.loads(view.topic("mystery")[0]) == {"k": [1, 2]}
    assert [m[1] for m in view.messages if m[0] == "chatter"] == [1, 2, 3, 6, 7, 8, 9, 10, 11, 12]
    assert view.metadata[MD_RECORDING]["host"] == "rig"
    assert main(["bag", "export", str(bag), "--json", str(out)]) == 1  # exists
    assert "already exists" in capsys.readouterr().err


def test_bag_export_blobs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "b.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    h.publish("camera/debug", Text(text="frame"), blobs=[b"\x89PNG...", b"more"])
    h.close()
    assert main(["bag", "export", str(out), "--json", str(tmp_path / "drop.mcap")]) == 0
    assert "2 blob frames dropped" in capsys.readouterr().out
    assert main(["bag", "export", str(out), "--json", str(tmp_path / "keep.mcap"), "--blobs", "base64"]) == 0
    kept = check_official(tmp_path / "keep.mcap")
    assert json.loads(kept.topic("_palpa/blobs/camera/debug")[0]) == {"blobs": ["iVBORy4uLg==", "bW9yZQ=="]}


def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bag", "info", str(tmp_path / "missing.mcap")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("palpa bag: ") and "no such recording" in err and "\n" not in err
    existing = tmp_path / "e.mcap"
    existing.write_bytes(b"x")
    assert main(["record", "-o", str(existing), "--bus", "ipc:///tmp/palpa-nobus-h6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already exists" in err[0]
    bag = _bag(tmp_path)
    assert main(["play", str(bag), "--rate", "0", "--bus", "ipc:///tmp/palpa-nobus-h6"]) == 2
    assert "rate" in capsys.readouterr().err
    assert main(["play", str(bag), "--remap", "nonsense"]) == 1
    assert "FROM:=TO" in capsys.readouterr().err
