"""BagWriter: writes one chunked, indexed MCAP file, fast enough for the recorder's hot path.

Every record except three is serialised by the ``mcap`` library's own record classes (Header, Schema, Channel,
ChunkIndex, Metadata, Attachment, Statistics, DataEnd, SummaryOffset, Footer). The exceptions are on the hot
path: the Message records inside a chunk and the Message Index records after it are packed with one ``struct``
call each, because ``mcap.writer.Writer.add_message`` costs ~5 us per message here (about 200 k msg/s of 100 B,
measured) — half the recorder's whole budget at 100 k msg/s; and the Chunk record's header is packed by hand so
a chunk of large messages is not copied twice more through a RecordBuilder. The byte layouts are the spec's
(and ``mcap.records``'s); the tests read every file back with ``mcap.reader.make_reader``, CRCs checked.

Crash safety: Schema and Channel records are written straight into the data section (outside chunks) when they
are registered, and :meth:`BagWriter.flush` closes the open chunk and hands everything to the OS. Every write
outside a chunk's buffer ends with a provisional tail (DataEnd, a Footer without summary, the closing magic)
that the next write overwrites: a process killed between writes leaves a complete, footer-terminated MCAP file
without a summary section (the spec allows one), which the official ``mcap`` readers read as it is, up to the
last complete chunk; ``palpa bag recover`` adds the summary (indexes, statistics). While it writes, a BagWriter
holds an exclusive ``flock`` on its file, so ``recover --in-place`` can tell a live file from a dead writer's.
"""

from __future__ import annotations

import fcntl
import os
import struct
import sys
import zlib
from array import array
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import BinaryIO

import lz4.frame
import mcap
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from palpa.record.format import MAGIC, BagError

__all__ = ["COMPRESSIONS", "MAX_CHANNELS", "BagWriter", "lock_exclusive", "lock_many", "open_locked"]

MAX_CHANNELS = 0xFFFF
"""Channels one MCAP file can hold (its channel ids are uint16, 0 is reserved)."""

_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time
_MESSAGE_INDEX = struct.Struct("<BQHI")  # opcode, record length, channel id, byte length of the entries
_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, record length, start, end, uncompressed size, crc, name length
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_LITTLE = sys.byteorder == "little"
# DataEnd (no CRC) + a Footer with no summary section (summary_start 0) + the closing magic
_TAIL = struct.pack("<BQI", Opcode.DATA_END, 4, 0) + struct.pack("<BQQQI", Opcode.FOOTER, 20, 0, 0, 0) + MAGIC


def _compressor(name: str) -> Callable[[bytearray], bytes | bytearray]:
    if name == "zstd":
        return zstandard.ZstdCompressor(level=1).compress
    if name == "lz4":
        return lz4.frame.compress  # type: ignore[no-any-return]
    if name == "":
        return lambda data: data
    raise BagError(f"unknown compression {name!r}: expected one of zstd, lz4, none")


COMPRESSIONS = ("zstd", "lz4", "none")


def _pack_index(entries: list[int]) -> bytes:
    arr = array("Q", entries)
    if not _LITTLE:
        arr.byteswap()
    return arr.tobytes()


def lock_exclusive(fh: BinaryIO) -> bool:
    """Take the advisory lock (``flock``) a live :class:`BagWriter` holds on its file, without waiting; False when
    someone (a recorder, in this or another process) holds it. Released when ``fh`` is closed."""
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def open_locked(path: Path, overwrite: bool) -> BinaryIO:
    """``path`` opened for writing from byte 0, holding the lock of a live writer (``palpa bag recover --in-place``
    must not replace a file in use, nor another recorder overwrite it). The lock comes first and the file is emptied
    only once it is held: a file another live writer holds is refused ("in use") with every byte of it intact, even
    with ``overwrite``; without ``overwrite`` an existing file is refused."""
    try:
        # no O_TRUNC: opening must not destroy what a live writer is writing, whose lock we do not have yet
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | (0 if overwrite else os.O_EXCL), 0o666)
    except FileExistsError:
        raise BagError(f"{path} already exists (use --force / force: true to overwrite)") from None
    except OSError as exc:
        raise BagError(f"cannot create {path}: {exc}") from None
    fh = os.fdopen(fd, "wb")
    if not lock_exclusive(fh):
        fh.close()
        raise BagError(f"{path} is in use: a recorder is still writing it (it holds the file's lock); "
                       "record to another file, or stop that recorder first")
    fh.truncate(0)
    return fh


def lock_many(paths: list[Path]) -> list[BinaryIO]:
    """Hold the live-writer lock of every file in ``paths`` (to delete them: the stale pieces of an earlier split
    recording); :class:`BagError` naming the first one a live writer holds, and then none is held."""
    held: list[BinaryIO] = []
    try:
        for path in paths:
            fh: BinaryIO = open(path, "rb")  # noqa: SIM115 - returned open, closed by the caller
            held.append(fh)
            if not lock_exclusive(fh):
                raise BagError(f"{path} is in use: a recorder is still writing it (it holds the file's lock); "
                               "record to another file, or stop that recorder first")
    except BaseException:
        for fh in held:
            fh.close()
        raise
    return held


class BagWriter:
    """One MCAP file. ``add_message`` buffers into the open chunk; ``flush`` closes it; ``finish`` writes the
    summary and footer. Times are ns since the Unix epoch; ``sequence`` must fit MCAP's uint32.

    ``compression`` is ``zstd`` (level 1), ``lz4`` or ``none``; ``chunk_size`` is the uncompressed size (bytes)
    at which a chunk is closed even before the next ``flush``. ``fsync`` makes every flush also ``os.fsync``
    (survives power loss, not only a killed process).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        compression: str = "zstd",
        chunk_size: int = 1 << 20,
        fsync: bool = False,
        library: str = "",
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        name = "" if compression == "none" else compression
        self._compress = _compressor(name)
        self._compression = name
        self._chunk_size = chunk_size
        self._fsync = fsync
        self._file: BinaryIO = open_locked(self.path, overwrite)
        self._pos = 0
        self.written = 0
        """Bytes handed to the file so far (updated when a chunk closes; cheap to poll per message)."""
        self._buf = bytearray()
        self._index: dict[int, list[int]] = {}
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._channel_counts: dict[int, int] = {}
        self.message_count = 0
        self.start_time = 0
        self.end_time = 0
        self.finished = False
        self._write(MAGIC)
        lib = library or f"palpa; mcap-python/{mcap.__version__}"
        self._write_record(Header(profile="", library=lib))
        self._seal()

    # -- low level -------------------------------------------------------------------------------------
    def _write(self, data: bytes | bytearray | memoryview) -> None:
        self._file.write(data)
        self._pos += len(data)
        self.written = self._pos

    def _write_record(self, record: McapRecord) -> tuple[int, int]:
        rb = RecordBuilder()
        record.write(rb)
        data: bytes = rb.end()  # type: ignore[no-untyped-call]
        offset = self._pos
        self._write(data)
        return offset, len(data)

    def _seal(self) -> None:
        """Write the provisional tail after the data so far, without moving the write position (see the
        module docstring); the seek also hands Python's buffer to the OS."""
        self._file.write(_TAIL)
        self._file.seek(self._pos)

    @property
    def size(self) -> int:
        """Bytes written so far plus the open chunk (uncompressed): what splitting by size compares."""
        return self._pos + len(self._buf)

    @property
    def channels(self) -> Mapping[int, Channel]:
        return self._channels

    @property
    def schemas(self) -> Mapping[int, Schema]:
        return self._schemas

    # -- declarations ------------------------------------------------------------------------------------
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record now and return its id (1, 2, ...)."""
        schema_id = len(self._schemas) + 1
        if schema_id > 0xFFFF:
            raise BagError(f"{self.path}: more than 65535 schemas")
        schema = Schema(id=schema_id, name=name, encoding=encoding, data=data)
        self._schemas[schema_id] = schema
        self._write_record(schema)
        self._seal()
        return schema_id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: Mapping[str, str]) -> int:
        """Write a Channel record now and return its id (1, 2, ...). ``schema_id`` 0 means no schema."""
        channel_id = len(self._channels) + 1
        if channel_id > MAX_CHANNELS:
            raise BagError(f"{self.path}: more than {MAX_CHANNELS} channels")
        if schema_id and schema_id not in self._schemas:
            raise BagError(f"{self.path}: channel {topic!r} refers to unknown schema id {schema_id}")
        channel = Channel(id=channel_id, topic=topic, message_encoding=message_encoding, schema_id=schema_id,
                          metadata=dict(metadata))
        self._channels[channel_id] = channel
        self._write_record(channel)
        self._seal()
        return channel_id

    # -- data ----------------------------------------------------------------------------------------
    def add_message(self, channel_id: int, log_time: int, publish_time: int, sequence: int,
                    data: bytes | bytearray | memoryview) -> None:
        """Append one message to the open chunk (the hot path: no validation beyond what struct checks). A time or
        sequence out of MCAP's range raises :class:`BagError` and changes nothing."""
        try:  # packed before anything changes: a value out of range leaves the chunk and its index as they were
            head = _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id, sequence, log_time,
                                 publish_time)
        except struct.error:
            raise BagError(f"{self.path}: message not written: log_time {log_time}, publish_time {publish_time} "
                           f"(both 0..2**64-1 ns) or sequence {sequence} (0..2**32-1) out of range") from None
        buf = self._buf
        entries = self._index.get(channel_id)
        if entries is None:
            if channel_id not in self._channels:
                raise BagError(f"{self.path}: message on unregistered channel id {channel_id}")
            entries = self._index[channel_id] = []
        entries += (log_time, len(buf))
        buf += head
        buf += data
        if len(buf) >= self._chunk_size:
            self._close_chunk()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a Metadata record (string -> string) now, outside any chunk."""
        offset, length = self._write_record(Metadata(name=name, metadata=dict(data)))
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self._seal()

    def add_attachment(self, name: str, media_type: str, data: bytes, *, log_time: int,
                       create_time: int = 0) -> None:
        """Write an Attachment record (a file stored verbatim, e.g. the resolved launch file) now."""
        record = Attachment(create_time=create_time, log_time=log_time, name=name, media_type=media_type,
                            data=data)
        offset, length = self._write_record(record)
        self._seal()
        self._attachment_indexes.append(
            AttachmentIndex(offset=offset, length=length, create_time=create_time, log_time=log_time,
                            data_size=len(data), name=name, media_type=media_type)
        )

    def _close_chunk(self) -> None:
        if not self._buf:
            return
        data = self._buf  # compressed, checksummed and written as is: no copy of a possibly large buffer
        self._buf = bytearray()
        index = self._index
        self._index = {}
        start = min(min(e[0::2]) for e in index.values())
        end = max(max(e[0::2]) for e in index.values())
        compressed = self._compress(data)
        name = self._compression.encode()
        # the Chunk record, laid out as mcap.records.Chunk.write does, but without copying the data twice
        # through a RecordBuilder: start, end, uncompressed size, crc, compression, records
        body_len = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(compressed)
        chunk_offset = self._pos
        self._write(_CHUNK_HEAD.pack(Opcode.CHUNK, body_len, start, end, len(data), zlib.crc32(data), len(name))
                    + name + struct.pack("<Q", len(compressed)))
        self._write(compressed)
        chunk_length = self._pos - chunk_offset
        offsets: dict[int, int] = {}
        index_start = self._pos
        for channel_id, entries in index.items():
            offsets[channel_id] = self._pos
            packed = _pack_index(entries)
            self._write(_MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 6 + len(packed), channel_id, len(packed)))
            self._write(packed)
            count = len(entries) // 2
            self._channel_counts[channel_id] = self._channel_counts.get(channel_id, 0) + count
            self.message_count += count
        self._chunk_indexes.append(
            ChunkIndex(message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
                       chunk_length=chunk_length, message_index_offsets=offsets,
                       message_index_length=self._pos - index_start, compression=self._compression,
                       compressed_size=len(compressed), uncompressed_size=len(data))
        )
        self.start_time = start if len(self._chunk_indexes) == 1 else min(self.start_time, start)
        self.end_time = max(self.end_time, end)
        self._seal()

    def flush(self) -> None:
        """Close the open chunk (if any) and pass everything written to the OS (and the disk, with fsync)."""
        if self.finished:
            return
        self._close_chunk()
        self._file.flush()
        if self._fsync:
            os.fsync(self._file.fileno())

    def finish(self) -> None:
        """Close the open chunk, write DataEnd, the summary section and the footer, and close the file."""
        if self.finished:
            return
        self._close_chunk()
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._pos
        rb = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[McapRecord]) -> None:
            if not records:
                return
            begin = rb.count
            for r in records:
                r.write(rb)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                         group_length=rb.count - begin))

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [Statistics(
            message_count=self.message_count, schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=len(self._attachment_indexes),
            metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
            message_start_time=self.start_time, message_end_time=self.end_time,
            channel_message_counts=dict(sorted(self._channel_counts.items())))])
        group(Opcode.CHUNK_INDEX, list(self._chunk_indexes))
        group(Opcode.ATTACHMENT_INDEX, list(self._attachment_indexes))
        group(Opcode.METADATA_INDEX, list(self._metadata_indexes))
        summary_offset_start = summary_start + rb.count
        for o in offsets:
            o.write(rb)
        summary: bytes = rb.end()  # type: ignore[no-untyped-call]
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self._write(summary)
        self._write_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                  summary_crc=crc))
        self._write(MAGIC)
        self._file.truncate()  # nothing of a longer provisional tail may remain
        self.finished = True
        self._file.flush()
        if self._fsync:
            os.fsync(self._file.fileno())
        self._file.close()

    def abandon(self) -> None:
        """Flush and close WITHOUT a summary (after an error): the file stays recoverable with bag recover."""
        if self.finished:
            return
        try:
            self.flush()
        finally:
            self.finished = True
            self._file.close()
