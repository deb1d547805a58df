"""``palpa bag recover``: rebuild a valid, indexed MCAP from a file whose writer died (SIGKILL, power loss).

The recorder closes a chunk at least every ``flush_period_s``; everything up to the last complete chunk is read
back record by record (chunk CRCs checked) and written to a new file with a summary section. Drops are recounted
from the recorded sequence numbers (the recorder's own counters died with it) and stored as ``palpa.drops``;
``palpa.recovery`` says what was read and where the damage began.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, DataEnd, Metadata, Schema

from palpa.net.wire import SequenceTracker, TopicStats
from palpa.record.format import MD_DROPS, MD_RECOVERY, META_BLOBS_OF, BagError, dumps
from palpa.record.reader import ChannelInfo, RawRecord, ReadableRecords, channel_info
from palpa.record.writer import BagWriter

_FOOTER = struct.Struct("<BQQ")  # opcode, record length, summary start

__all__ = ["RecoverReport", "default_recovered_path", "recover"]


@dataclass
class RecoverReport:
    """What :func:`recover` found: messages kept, whether the source was complete, and where it broke."""

    source: Path
    output: Path
    messages: int = 0
    finalized: bool = False
    damage: str = ""
    drops: dict[str, dict[str, int]] = field(default_factory=dict)

    def text(self) -> str:
        state = "was complete" if self.finalized else f"ended early ({self.damage or 'no summary'})"
        gaps = sum(d["gaps"] for d in self.drops.values())
        return (f"recovered {self.messages} messages from {self.source} into {self.output}; the source {state}; "
                f"{gaps} messages missing by sequence number")


def _has_summary(fh: BinaryIO) -> bool:
    """Whether the file ends with a Footer that points at a summary section (a finished file)."""
    try:
        fh.seek(-(_FOOTER.size + 12 + 8), os.SEEK_END)
    except OSError:
        return False
    opcode, _length, summary_start = _FOOTER.unpack(fh.read(_FOOTER.size))
    return bool(opcode == Opcode.FOOTER and summary_start != 0)


def default_recovered_path(src: Path) -> Path:
    """``run.mcap`` -> ``run.recovered.mcap`` next to it."""
    return src.with_name(f"{src.stem}.recovered{src.suffix or '.mcap'}")


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str] | None = None, *,
            overwrite: bool = False) -> RecoverReport:
    """Copy every readable record of ``src`` into ``dst`` (default ``<stem>.recovered.mcap``) and finalise it."""
    source = Path(src)
    out = Path(dst) if dst is not None else default_recovered_path(source)
    if out.resolve() == source.resolve():
        raise BagError(f"{out}: the output must differ from the source (use --in-place to replace it)")
    report = RecoverReport(source, out)
    try:
        fh = open(source, "rb")  # noqa: SIM115 - closed in finally below
    except OSError as exc:
        raise BagError(f"cannot read {source}: {exc}") from None
    writer: BagWriter | None = None
    try:
        writer = BagWriter(out, overwrite=overwrite)
        schema_map: dict[int, int] = {0: 0}
        channel_map: dict[int, int] = {}
        infos: dict[int, ChannelInfo] = {}
        tracker = SequenceTracker()
        stats: dict[str, TopicStats] = {}
        records = ReadableRecords(fh, source)  # the first unreadable record ends the usable prefix
        for rec in records:
            if isinstance(rec, RawRecord):
                new = channel_map.get(rec.channel_id)
                if new is None:
                    report.damage = f"message on channel {rec.channel_id} before its Channel record"
                    break
                writer.add_message(new, rec.log_time, rec.publish_time, rec.sequence, rec.data)
                info = infos[rec.channel_id]
                if not info.blobs_of:
                    report.messages += 1
                    tracker.observe(info.topic, info.node, info.seq_base + rec.sequence,
                                    stats.setdefault(info.topic, TopicStats()))
            elif isinstance(rec, Schema):
                if rec.id not in schema_map:
                    schema_map[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id not in channel_map:
                    md = dict(rec.metadata)
                    if META_BLOBS_OF in md:
                        md[META_BLOBS_OF] = str(channel_map.get(int(md[META_BLOBS_OF]), 0))
                    channel_map[rec.id] = writer.register_channel(rec.topic, rec.message_encoding,
                                                                  schema_map.get(rec.schema_id, 0), md)
                    infos[rec.id] = channel_info(rec)
            elif isinstance(rec, Metadata):
                if rec.name not in (MD_DROPS, MD_RECOVERY):
                    writer.add_metadata(rec.name, rec.metadata)
            elif isinstance(rec, Attachment):
                writer.add_attachment(rec.name, rec.media_type, rec.data, log_time=rec.log_time,
                                      create_time=rec.create_time)
            elif isinstance(rec, DataEnd):
                # a footer without a summary is the provisional tail of a recorder that was killed
                report.finalized = _has_summary(fh)
                break
        report.damage = report.damage or records.damage
        report.drops = {t: s.as_dict() for t, s in stats.items()}
        writer.add_metadata(MD_DROPS, {t: dumps(d) for t, d in report.drops.items()})
        writer.add_metadata(MD_RECOVERY, {
            "source": str(source),
            "source_bytes": str(source.stat().st_size),
            "messages": str(report.messages),
            "source_finalized": "true" if report.finalized else "false",
            "damage": report.damage,
        })
        writer.finish()
    except BaseException:
        if writer is not None and not writer.finished:
            writer.abandon()
            out.unlink(missing_ok=True)
        raise
    finally:
        fh.close()
    return report
