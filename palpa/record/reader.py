"""Read a palpa recording back as envelopes: :func:`iter_bag` yields :class:`BagMessage` in file order.

File order is receive order (the recorder appends as messages arrive), which is what replay wants; it does not
need the summary section, so a file left by a killed recorder still plays up to its last complete chunk.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import msgspec
from mcap.exceptions import InvalidMagic
from mcap.records import Channel, DataEnd, McapRecord, Message
from mcap.stream_reader import StreamReader

from palpa.record.format import (
    META_BLOBS_OF,
    META_LATCHED,
    META_PUBLISHER,
    META_SEQ_BASE,
    META_TYPE,
    BagError,
    split_path,
    split_pieces,
)

__all__ = ["BagMessage", "ChannelInfo", "channel_info", "iter_bag", "iter_file", "resolve_bag_paths"]

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


def iter_file(
    path: Path,
    *,
    file_index: int = 0,
    on_damage: Callable[[str], None] | None = None,
    on_record: Callable[[McapRecord], None] | None = None,
) -> Iterator[BagMessage]:
    """Messages of one file in file order, blobs joined back to their message.

    A truncated or damaged file raises :class:`BagError` after yielding everything before the damage, unless
    ``on_damage`` is given: it is then called with a description and iteration simply ends. ``on_record`` sees
    every non-message record (Header, Schema, Channel, Metadata, Attachment) as it is read.
    """
    channels: dict[int, ChannelInfo] = {}
    pending: BagMessage | None = None
    count = 0
    damage = ""
    try:
        with open(path, "rb") as fh:
            records = StreamReader(fh, validate_crcs=True).records
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except InvalidMagic:
                    raise BagError(f"{path}: not an MCAP file (bad magic bytes)") from None
                except Exception as exc:  # noqa: BLE001 - any parse failure means the rest is unreadable
                    damage = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                    break
                if isinstance(rec, Message):
                    info = channels.get(rec.channel_id)
                    if info is None:
                        raise BagError(f"{path}: message on channel {rec.channel_id} before its Channel record")
                    if info.blobs_of:
                        if (pending is not None and pending.channel_id == info.blobs_of
                                and (pending.seq - channels[info.blobs_of].seq_base) == rec.sequence):
                            pending = pending._replace(blobs=tuple(_blob_decoder.decode(rec.data)))
                        continue
                    if pending is not None:
                        yield pending
                    count += 1
                    pending = BagMessage(info.topic, info.type, info.node, info.seq_base + rec.sequence,
                                         rec.log_time, rec.publish_time, rec.data, (), info.latched,
                                         rec.channel_id, file_index)
                    continue
                if isinstance(rec, Channel):
                    channels[rec.id] = channel_info(rec)
                elif isinstance(rec, DataEnd):
                    break  # the summary section repeats what we have seen
                if on_record is not None:
                    on_record(rec)
    except OSError as exc:
        raise BagError(f"cannot read {path}: {exc}") from None
    if pending is not None:
        yield pending
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
