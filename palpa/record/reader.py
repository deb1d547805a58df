"""Read a palpa recording back as envelopes: :func:`iter_bag` yields :class:`BagMessage` in file order.

File order is receive order (the recorder appends as messages arrive), which is what replay wants; it does not
need the summary section, so a file left by a killed recorder still plays up to its last complete chunk.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import BinaryIO, NamedTuple

import lz4.frame
import msgspec
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import InvalidMagic
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Header, McapRecord, Metadata, Schema

from palpa.record.format import (
    LAUNCH_ATTACHMENT,
    MAGIC,
    META_BLOBS_OF,
    META_LATCHED,
    META_PUBLISHER,
    META_SEQ_BASE,
    META_TYPE,
    BagError,
    split_path,
    split_pieces,
)

__all__ = [
    "BagMessage",
    "ChannelInfo",
    "RawRecord",
    "channel_info",
    "iter_bag",
    "iter_file",
    "ReadableRecords",
    "iter_records",
    "launch_text_of",
    "resolve_bag_paths",
]

_blob_decoder = msgspec.msgpack.Decoder(list[bytes])


class BagMessage(NamedTuple):
    """One recorded envelope. Times are ns since the Unix epoch; ``seq`` is the full envelope sequence number."""

    topic: str
    type: str
    node: str
    seq: int
    log_time: int
    publish_time: int
    payload: bytes
    blobs: tuple[bytes, ...]
    latched: bool
    channel_id: int
    file_index: int


class ChannelInfo(NamedTuple):
    """What palpa's channel metadata says about a channel (defaults for MCAP files written by other tools)."""

    topic: str
    type: str
    node: str
    latched: bool
    seq_base: int
    blobs_of: int


def channel_info(channel: Channel) -> ChannelInfo:
    """Parse a channel's palpa metadata; a foreign channel gets its schema-less defaults."""
    md = channel.metadata
    try:
        seq_base = int(md.get(META_SEQ_BASE, "0"))
        blobs_of = int(md.get(META_BLOBS_OF, "0"))
    except ValueError:
        raise BagError(f"channel {channel.topic!r}: bad palpa metadata {md}") from None
    return ChannelInfo(channel.topic, md.get(META_TYPE, ""), md.get(META_PUBLISHER, ""),
                       md.get(META_LATCHED) == "true", seq_base, blobs_of)


def resolve_bag_paths(specs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Files to read, in order. Each spec is a file; a directory (its ``*.mcap`` files, sorted); or the base
    name of a split recording (``run.mcap`` -> ``run-0001.mcap``, ``run-0002.mcap``, ...)."""
    items = [specs] if isinstance(specs, str | os.PathLike) else list(specs)
    if not items:
        raise BagError("no recording given")
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_file():
            out.append(p)
        elif p.is_dir():
            found = sorted(p.glob("*.mcap"))
            if not found:
                raise BagError(f"{p}: directory holds no .mcap files")
            out.extend(found)
        else:
            pieces = split_pieces(p)
            if not pieces:
                raise BagError(f"{p}: no such recording (nor split pieces {split_path(p, 1).name}, ...)")
            out.extend(pieces)
    return out


class RawRecord(NamedTuple):
    """A Message record, unparsed beyond its fixed fields (cheaper than mcap.records.Message)."""

    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: bytes


_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_FIELDS = struct.Struct("<HIQQ")


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise BagError(f"unsupported chunk compression {chunk.compression!r}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise BagError("chunk CRC mismatch")
    return bytes(data)


_PARSERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.METADATA: Metadata.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.DATA_END: DataEnd.read,
}
_MAX_RECORD = 4 << 30


def _walk_chunk(data: bytes) -> Iterator[McapRecord | RawRecord]:
    pos, end = 0, len(data)
    while pos < end:
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        body = pos + 9
        pos = body + length
        if pos > end:
            raise BagError("a record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            cid, seq, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(data, body)
            yield RawRecord(cid, seq, log_time, publish_time, data[body + 22:pos])
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            yield _PARSERS[opcode](ReadDataStream(io.BytesIO(data[body:pos])))


def iter_records(fh: BinaryIO) -> Iterator[McapRecord | RawRecord]:
    """The data section of an MCAP stream in file order: Header, Schema, Channel, Metadata, Attachment records
    (parsed by the ``mcap`` library), messages as :class:`RawRecord`, then DataEnd, where it stops.

    Chunks are decompressed and CRC-checked, then walked one message at a time, and index records are skipped
    unparsed: ``mcap``'s StreamReader parses a whole chunk and every Message Index entry up front, which stalls
    a player for 10-20 ms at each 1 MB chunk. Raises :class:`BagError` (or a parser's error) where the data is
    damaged or ends before DataEnd (a file whose writer never finished it).
    """
    if fh.read(8) != MAGIC:
        raise InvalidMagic("file does not start with the MCAP magic bytes")
    read = fh.read
    while True:
        head = read(9)
        if len(head) < 9:
            raise BagError("the data ends without a DataEnd record (the writer did not finish the file)"
                           if not head else "truncated record header")
        opcode, length = _RECORD_HEAD.unpack(head)
        if length > _MAX_RECORD:
            raise BagError(f"record of {length} bytes: the file is damaged")
        body = read(length)
        if len(body) < length:
            raise BagError("truncated record")
        if opcode == Opcode.CHUNK:
            yield from _walk_chunk(_decompress(Chunk.read(ReadDataStream(io.BytesIO(body)))))
        elif opcode == Opcode.MESSAGE:
            cid, seq, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(body, 0)
            yield RawRecord(cid, seq, log_time, publish_time, body[22:])
        elif opcode in _PARSERS:
            rec = _PARSERS[opcode](ReadDataStream(io.BytesIO(body)))
            yield rec
            if opcode == Opcode.DATA_END:
                return
        # Message Index, Chunk Index and other index/summary records: not needed to read forward


class ReadableRecords:
    """The records of an open MCAP file up to the first one that cannot be read (a file whose writer died).

    Iterate it; afterwards ``damage`` says what stopped the reading ("" when the file was read to its end). A file
    that is not MCAP at all raises :class:`BagError` at once.
    """

    def __init__(self, fh: BinaryIO, source: str | os.PathLike[str]) -> None:
        self._records = iter_records(fh)
        self._source = source
        self.damage = ""

    def __iter__(self) -> Iterator[McapRecord | RawRecord]:
        while True:
            try:
                rec = next(self._records)
            except StopIteration:
                return
            except InvalidMagic:
                raise BagError(f"{self._source}: not an MCAP file (bad magic bytes)") from None
            except Exception as exc:  # noqa: BLE001 - any parse failure means the rest is unreadable
                self.damage = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                return
            yield rec


def iter_file(
    path: Path,
    *,
    file_index: int = 0,
    on_damage: Callable[[str], None] | None = None,
    on_record: Callable[[McapRecord], None] | None = None,
) -> Iterator[BagMessage]:
    """Messages of one file in file order, blobs joined back to their message (each message is yielded as soon
    as it is read: no look-ahead, so a player's timing does not wait on the next chunk).

    A truncated or damaged file raises :class:`BagError` after yielding everything before the damage, unless
    ``on_damage`` is given: it is then called with a description and iteration simply ends. ``on_record`` sees
    every non-message record (Header, Schema, Channel, Metadata, Attachment) as it is read.
    """
    channels: dict[int, ChannelInfo] = {}
    blobs: tuple[int, int, tuple[bytes, ...]] | None = None  # (main channel, sequence, frames), written first
    count = 0
    damage = ""
    try:
        with open(path, "rb") as fh:
            records = ReadableRecords(fh, path)
            for rec in records:
                if isinstance(rec, RawRecord):
                    info = channels.get(rec.channel_id)
                    if info is None:
                        raise BagError(f"{path}: message on channel {rec.channel_id} before its Channel record")
                    if info.blobs_of:
                        blobs = (info.blobs_of, rec.sequence, tuple(_blob_decoder.decode(rec.data)))
                        continue
                    frames: tuple[bytes, ...] = ()
                    if blobs is not None:
                        if blobs[0] == rec.channel_id and blobs[1] == rec.sequence:
                            frames = blobs[2]
                        blobs = None
                    count += 1
                    yield BagMessage(info.topic, info.type, info.node, info.seq_base + rec.sequence,
                                     rec.log_time, rec.publish_time, rec.data, frames, info.latched,
                                     rec.channel_id, file_index)
                    continue
                if isinstance(rec, Channel):
                    channels[rec.id] = channel_info(rec)
                if on_record is not None:
                    on_record(rec)
            damage = records.damage
    except OSError as exc:
        raise BagError(f"cannot read {path}: {exc}") from None
    if damage:
        text = (f"{path}: unreadable after message {count} ({damage}); the file was not closed cleanly "
                f"(`palpa bag recover {path}` rebuilds it)")
        if on_damage is None:
            raise BagError(text)
        on_damage(text)


def iter_bag(
    paths: Sequence[Path],
    *,
    on_damage: Callable[[str], None] | None = None,
    on_record: Callable[[McapRecord], None] | None = None,
) -> Iterator[BagMessage]:
    """:func:`iter_file` over several files (the pieces of a split recording), in order."""
    for i, path in enumerate(paths):
        yield from iter_file(path, file_index=i, on_damage=on_damage, on_record=on_record)


def launch_text_of(bag: str | os.PathLike[str]) -> str | None:
    """The resolved launch file a recording carries (attachment ``launch.resolved.yaml``, written when the
    recorder opens each piece, so only the start of the first piece is read), or None if it has none."""
    from mcap.stream_reader import StreamReader

    for path in resolve_bag_paths(bag)[:1]:
        try:
            with open(path, "rb") as fh:
                for rec in StreamReader(fh, emit_chunks=True).records:
                    if isinstance(rec, Attachment) and rec.name == LAUNCH_ATTACHMENT:
                        return bytes(rec.data).decode("utf-8", errors="replace")
                    if isinstance(rec, Chunk | DataEnd):
                        break  # messages have begun: the attachment would have come first
        except (OSError, InvalidMagic) as exc:
            raise BagError(f"{path}: cannot read: {exc}") from None
    return None
