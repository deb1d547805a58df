"""BagWriter: every file it writes is valid MCAP for the official reader, indexes point at the right bytes, and a
flushed but unfinished file is readable up to its last chunk."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import msgspec
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, MessageIndex
from mcap.stream_reader import StreamReader

from palpa.record.format import BagError
from palpa.record.reader import iter_file
from palpa.record.testing import check_official
from palpa.record.writer import BagWriter


def _payload(i: int) -> bytes:
    return msgspec.msgpack.encode({"text": f"m{i}", "stamp_ns": i})


def _fill(w: BagWriter, n: int, channels: int = 2) -> list[tuple[int, int, bytes]]:
    sid = w.register_schema("Text", "jsonschema", b'{"type": "object"}')
    cids = [w.register_channel(f"t{c}", "msgpack", sid, {"palpa.publisher": "p"}) for c in range(channels)]
    out = []
    for i in range(n):
        cid = cids[i % channels]
        w.add_message(cid, 1_000 + i, 500 + i, i + 1, _payload(i))
        out.append((cid, i + 1, _payload(i)))
    return out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_official_reader_reads_everything(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "a.mcap"
    w = BagWriter(path, compression=compression, chunk_size=2_000)
    sent = _fill(w, 500)
    w.add_metadata("palpa.recording", {"palpa_version": "x"})
    w.add_attachment("launch.resolved.yaml", "application/yaml", b"nodes: []\n", log_time=7)
    w.finish()
    view = check_official(path)
    assert view.statistics.message_count == 500
    assert view.statistics.chunk_count > 10  # chunk_size forced many chunks
    assert view.statistics.channel_message_counts == {1: 250, 2: 250}
    assert [(m[1], m[4]) for m in view.messages] == [(s, p) for _, s, p in sent]
    assert [m[2] - m[3] for m in view.messages] == [500] * 500  # log and publish time kept apart
    assert view.metadata["palpa.recording"] == {"palpa_version": "x"}
    assert view.attachments["launch.resolved.yaml"] == b"nodes: []\n"
    assert view.schemas[1].encoding == "jsonschema" and view.channels[1].message_encoding == "msgpack"


def test_message_indexes_point_at_their_messages(tmp_path: Path) -> None:
    """The two records we pack by hand (Message, MessageIndex) must agree with the chunk contents."""
    path = tmp_path / "idx.mcap"
    w = BagWriter(path, chunk_size=3_000)
    _fill(w, 300, channels=3)
    w.finish()
    records = list(StreamReader(io.BytesIO(path.read_bytes()), emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    indexes = [r for r in records if isinstance(r, MessageIndex)]
    chunk_indexes = [r for r in records if isinstance(r, ChunkIndex)]
    assert len(chunk_indexes) == len(chunks) > 3
    checked = 0
    by_chunk = iter(indexes)
    for chunk, cidx in zip(chunks, chunk_indexes, strict=True):
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        assert zlib.crc32(data) == chunk.uncompressed_crc
        times = []
        for channel_id in cidx.message_index_offsets:
            mi = next(by_chunk)
            assert mi.channel_id == channel_id
            for log_time, offset in mi.records:
                opcode, _length, cid, _seq, lt = struct.unpack_from("<BQHIQ", data, offset)
                assert (opcode, cid, lt) == (0x05, channel_id, log_time)
                times.append(log_time)
                checked += 1
        assert (cidx.message_start_time, cidx.message_end_time) == (min(times), max(times))
    assert checked == 300


def test_flushed_unfinished_file_reads_up_to_the_last_chunk(tmp_path: Path) -> None:
    path = tmp_path / "open.mcap"
    w = BagWriter(path)
    _fill(w, 40)
    w.flush()
    for i in range(10):  # in the open chunk only: not on disk yet
        w.add_message(1, 9_000 + i, 9_000 + i, 1_000 + i, b"\x80")
    got = list(iter_file(Path(path), on_damage=lambda text: None))
    assert [m.seq for m in got] == list(range(1, 41))
    w.abandon()
    # abandoned: flushed, no summary, but a provisional footer: read whole, by palpa and the official reader
    assert len(list(iter_file(path))) == 50
    with open(path, "rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) == 50


def test_refuses_to_overwrite_and_checks_channels(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(BagError, match="already exists"):
        BagWriter(path)
    assert path.read_bytes() == b"precious"
    w = BagWriter(tmp_path / "y.mcap")
    with pytest.raises(BagError, match="unregistered channel"):
        w.add_message(3, 1, 1, 1, b"\x80")
    with pytest.raises(BagError, match="unknown schema"):
        w.register_channel("t", "msgpack", 9, {})
    with pytest.raises(BagError, match="compression"):
        BagWriter(tmp_path / "z.mcap", compression="gzip")
    w.finish()
    check_official(tmp_path / "y.mcap")  # an empty recording is still a valid file


def test_not_an_mcap_file(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.mcap"
    bogus.write_bytes(b"hello, this is not mcap at all")
    with pytest.raises(BagError, match="not an MCAP file"):
        list(iter_file(bogus))
