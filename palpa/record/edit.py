"""``palpa bag filter|cut|merge``: new recordings made from old ones, byte for byte.

One function, :func:`rewrite`, does all three: it reads one or more recordings (each a file, a split set or a
directory), keeps the messages of the selected topics within a time range, and writes them into one MCAP file
with the official ``mcap`` Writer. What it keeps:

* every payload, sequence number, publish and log time exactly as recorded, and each channel's palpa metadata
  (type, publisher, latched, sequence epoch); blobs go on their companion channel right before their message;
* the schemas of the channels kept; every metadata record (``palpa.recording``, ``palpa.nodes``, ...) and every
  attachment (the resolved launch file first of all, before any message, where ``palpa launch`` looks for it);
* for a cut, the last message of every latched topic before the start, written at the start (as a split piece
  opens with them), so the cut still replays with its scan plan and calibration.

Recordings merged are interleaved by log time; their channels stay apart (a talker in two runs is two channels
whose sequence numbers each count from their own start). A metadata record ``palpa.edit`` says what was done.
"""

from __future__ import annotations

import heapq
import os
import struct
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, McapRecord, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

import palpa
from palpa.atomic import written_beside
from palpa.net.wire import SequenceTracker, TopicStats
from palpa.record.format import (
    BLOBS_SCHEMA,
    BLOBS_SCHEMA_NAME,
    BLOBS_TOPIC_PREFIX,
    LAUNCH_ATTACHMENT,
    MD_DROPS,
    MESSAGE_ENCODING,
    META_BLOBS_OF,
    SCHEMA_ENCODING,
    BagError,
    TopicFilter,
    dumps,
)
from palpa.record.reader import BagMessage, iter_file

__all__ = ["EditReport", "rewrite"]

_blobs_encoder = msgspec.msgpack.Encoder()


@dataclass
class EditReport:
    """What :func:`rewrite` wrote."""

    output: Path
    messages: int = 0
    topics: set[str] = field(default_factory=set)
    held_latched: int = 0
    duplicates: int = 0
    drops: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per topic, the sequence gaps of what was written (``palpa.drops``, recounted as recover does: the
    inputs' counts were of whole recordings, every topic and the whole time range)."""

    def text(self) -> str:
        """The summary line the CLI prints."""
        extra = []
        if self.held_latched:
            extra.append(f"{self.held_latched} latched messages from before the start kept at the start")
        if self.duplicates:
            extra.append(f"{self.duplicates} repeated copies dropped (latched copies opening split pieces, the same "
                         "message in two merged recordings)")
        return (f"wrote {self.messages} messages on {len(self.topics)} topics to {self.output}"
                + (f" ({'; '.join(extra)})" if extra else ""))


@dataclass
class _Source:
    """One file of one input recording: its channels and schemas as read so far."""

    recording: int
    path: Path
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)

    def on_record(self, rec: McapRecord) -> None:
        if isinstance(rec, Channel):
            self.channels[rec.id] = rec
        elif isinstance(rec, Schema):
            self.schemas[rec.id] = rec

    def messages(self, index: int) -> Iterator[tuple[_Source, BagMessage]]:
        for m in iter_file(self.path, file_index=index, on_record=self.on_record):
            yield self, m


def _side_records(path: Path) -> tuple[list[Attachment], list[Metadata]]:
    """Attachments and metadata of one file (chunks are skipped unopened)."""
    attachments: list[Attachment] = []
    metadata: list[Metadata] = []
    try:
        with open(path, "rb") as fh:
            for rec in StreamReader(fh, emit_chunks=True, skip_magic=False).records:
                if isinstance(rec, Attachment):
                    attachments.append(rec)
                elif isinstance(rec, Metadata):
                    metadata.append(rec)
    except (OSError, McapError, ValueError, EOFError, struct.error) as exc:  # struct: a record cut mid-length
        raise BagError(f"{path}: cannot read ({type(exc).__name__}: {exc}); a file whose recorder was killed "
                       f"needs `palpa bag recover {path}` first") from None
    return attachments, metadata


class _Out:
    """The output file's registry: schemas and channels by what they are, so repeated ones are written once."""

    def __init__(self, writer: Writer) -> None:
        self.w = writer
        self._schemas: dict[tuple[str, str, bytes], int] = {}
        self._channels: dict[tuple[object, ...], int] = {}

    def schema(self, schema: Schema | None) -> int:
        if schema is None:
            return 0
        key = (schema.name, schema.encoding, bytes(schema.data))
        if key not in self._schemas:
            self._schemas[key] = self.w.register_schema(schema.name, schema.encoding, bytes(schema.data))
        return self._schemas[key]

    def channel(self, src: _Source, channel_id: int) -> int:
        ch = src.channels[channel_id]
        sid = self.schema(src.schemas.get(ch.schema_id)) if ch.schema_id else 0
        key = (src.recording, ch.topic, ch.message_encoding, sid, tuple(sorted(ch.metadata.items())))
        if key not in self._channels:
            self._channels[key] = self.w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
        return self._channels[key]

    def blobs_channel(self, topic: str, main: int) -> int:
        key = ("blobs", main)
        if key not in self._channels:
            sid = self.schema(Schema(id=0, data=BLOBS_SCHEMA, encoding=SCHEMA_ENCODING, name=BLOBS_SCHEMA_NAME))
            self._channels[key] = self.w.register_channel(BLOBS_TOPIC_PREFIX + topic, MESSAGE_ENCODING, sid,
                                                          {META_BLOBS_OF: str(main)})
        return self._channels[key]

    def message(self, src: _Source, m: BagMessage, log_time: int) -> None:
        cid = self.channel(src, m.channel_id)
        seq = m.seq & 0xFFFF_FFFF  # the channel's palpa.seq_base (a multiple of 2**32, copied) holds the rest
        if m.blobs:
            self.w.add_message(self.blobs_channel(m.topic, cid), log_time=log_time, publish_time=m.publish_time,
                               sequence=seq, data=_blobs_encoder.encode(list(m.blobs)))
        self.w.add_message(cid, log_time=log_time, publish_time=m.publish_time, sequence=seq, data=m.payload)


def rewrite(recordings: Sequence[Sequence[Path]], out: str | os.PathLike[str], *, topics: TopicFilter | None = None,
            start_ns: int | None = None, end_ns: int | None = None, operation: str = "filter",
            overwrite: bool = False) -> EditReport:
    """Write the messages of ``recordings`` (each a list of files: one recording, its split pieces in order) whose
    topic passes ``topics`` and whose log time lies in ``[start_ns, end_ns]`` (absolute ns; None: open) into the
    MCAP file ``out``. Files are read in full before anything replaces ``out``; a damaged input raises
    :class:`BagError` and leaves no output."""
    output = Path(out)
    if not recordings or not all(recordings):
        raise BagError("no recording given")
    inputs = [p.resolve() for rec in recordings for p in rec]
    if output.resolve() in inputs:
        raise BagError(f"{output} is also an input: write the result to another file")
    if output.exists() and not overwrite:
        raise BagError(f"{output} already exists (use --force to overwrite)")
    if start_ns is not None and end_ns is not None and end_ns < start_ns:
        raise BagError("the end of the range lies before its start")
    keep = topics or TopicFilter(always=())
    report = EditReport(output)
    sides = [(p, _side_records(p)) for rec in recordings for p in rec]
    with written_beside(output) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(library=f"palpa/{palpa.__version__} bag {operation}")
        seen: set[tuple[str, bytes]] = set()
        for _path, (attachments, _md) in sides:  # the launch file before any message (launch_text_of)
            for att in sorted(attachments, key=lambda a: a.name != LAUNCH_ATTACHMENT):
                if (att.name, bytes(att.data)) not in seen:
                    seen.add((att.name, bytes(att.data)))
                    w.add_attachment(att.create_time, att.log_time, att.name, att.media_type, bytes(att.data))
        _copy_messages(_Out(w), recordings, keep, start_ns, end_ns, report)
        if not report.messages:
            raise BagError("no message of the recording passes the topic filter and lies in the time range: "
                           "nothing written")
        for _path, (_att, metadata) in sides:
            for md in metadata:
                if md.name != MD_DROPS:
                    w.add_metadata(md.name, dict(md.metadata))
        w.add_metadata(MD_DROPS, {t: dumps(d) for t, d in report.drops.items()})
        w.add_metadata("palpa.edit", {
            "operation": operation, "sources": dumps([str(p) for rec in recordings for p in rec]),
            "topics": dumps([p.pattern for p in keep.include]), "exclude": dumps([p.pattern for p in keep.exclude]),
            "start_ns": str(start_ns or ""), "end_ns": str(end_ns or ""), "note": report.text()})
        w.finish()  # type: ignore[no-untyped-call]
    return report


def _copy_messages(out: _Out, recordings: Sequence[Sequence[Path]], keep: Callable[[str], bool],
                   start_ns: int | None, end_ns: int | None, report: EditReport) -> None:
    streams = [_chain([_Source(r, p).messages(i) for i, p in enumerate(rec)]) for r, rec in enumerate(recordings)]
    held: dict[tuple[int, str, str], tuple[_Source, BagMessage]] = {}
    last_latched: dict[tuple[int, str, str], int] = {}
    streams_of = _Streams()
    tracker, stats = SequenceTracker(), dict[str, TopicStats]()
    started = start_ns is None
    for src, m in heapq.merge(*streams, key=lambda item: item[1].log_time):
        if not keep(m.topic):
            continue
        key = (src.recording, m.topic, m.node)
        if start_ns is not None and m.log_time < start_ns:
            if m.latched:
                held[key] = (src, m)
            continue
        if end_ns is not None and m.log_time > end_ns:
            continue
        if not started:
            started = True
            for hkey, (hsrc, hm) in held.items():
                out.message(hsrc, hm, int(start_ns or hm.log_time))
                last_latched[hkey] = hm.seq
                report.held_latched += 1
                report.messages += 1
                report.topics.add(hm.topic)
        if m.latched:
            if last_latched.get(key) == m.seq:
                report.duplicates += 1
                continue  # the copy of a latched message that opens the next piece of a split recording
            last_latched[key] = m.seq
        if len(recordings) > 1 and not streams_of.take(src, m, recordings):
            report.duplicates += 1
            continue
        out.message(src, m, m.log_time)
        report.messages += 1
        report.topics.add(m.topic)
        # not the latched copies held from before the start: their numbers lie before the range, not gaps in it
        tracker.observe(m.topic, m.node, m.seq, stats.setdefault(m.topic, TopicStats()))
    report.drops = {t: s.as_dict() for t, s in stats.items()}


class _Streams:
    """Merging: one publisher's stream of one topic must come from one recording at a time. The same message in
    two recordings (two recorders on one bus) is kept once; two recordings whose streams of one publisher and topic
    interleave would replay as one stream whose sequence numbers jump back and forth, which subscribers drop as
    duplicates, so that is refused. One recording after another (runs of the same graph) is a restart, as live."""

    _WINDOW = 256

    def __init__(self) -> None:
        self._last: dict[tuple[str, str], int] = {}
        self._done: dict[tuple[str, str], set[int]] = {}
        self._recent: dict[tuple[str, str], dict[tuple[int, bytes], None]] = {}

    def take(self, src: _Source, m: BagMessage, recordings: Sequence[Sequence[Path]]) -> bool:
        """False for a message already taken from another recording; raises on interleaved streams."""
        key = (m.topic, m.node)
        recent = self._recent.setdefault(key, {})
        ident = (m.seq, m.payload)
        if ident in recent:
            return False
        last = self._last.get(key, src.recording)
        if last != src.recording:
            done = self._done.setdefault(key, set())
            if src.recording in done:
                raise BagError(f"{m.topic} from {m.node!r} interleaves in {recordings[last][0]} and "
                               f"{recordings[src.recording][0]} with different messages: a replay would mix two "
                               "streams of one publisher (leave the topic out of one with `palpa bag filter "
                               "--exclude` first)")
            done.add(last)
        self._last[key] = src.recording
        recent[ident] = None
        if len(recent) > self._WINDOW:
            del recent[next(iter(recent))]
        return True


def _chain(parts: list[Iterator[tuple[_Source, BagMessage]]]) -> Iterator[tuple[_Source, BagMessage]]:
    for part in parts:
        yield from part
