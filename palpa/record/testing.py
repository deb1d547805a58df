"""Helpers for tests of anything that reads or writes recordings (shipped with the runtime, like palpa.testing).

* :func:`write_bag` makes a recording with exact times, as the recorder would have written it;
* :func:`check_official` opens a file with the official ``mcap`` reader (both the seeking and the streaming
  reader, CRCs validated) and returns what it saw, so a test fails if any file we write is not valid MCAP;
* :func:`play_in_memory` plays a recording with the Player node on an in-memory bus and returns what was sent.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.reader import NonSeekingReader, make_reader

from palpa.record.format import (
    MESSAGE_ENCODING,
    META_LATCHED,
    META_PUBLISHER,
    META_TYPE,
    SCHEMA_ENCODING,
    schema_bytes,
)
from palpa.record.writer import BagWriter

if TYPE_CHECKING:
    from palpa.node.node import RawMessage
    from palpa.record.player import Player

__all__ = ["OfficialView", "Rec", "check_official", "play_in_memory", "write_bag"]


@dataclass(frozen=True)
class Rec:
    """One message for :func:`write_bag`. Times in ns; ``payload`` is the msgpack wire payload."""

    topic: str
    log_time: int
    payload: bytes
    seq: int
    type: str = "Text"
    node: str = "talker"
    publish_time: int | None = None
    latched: bool = False


def write_bag(path: str | os.PathLike[str], messages: Iterable[Rec], *, chunk_size: int = 1 << 20,
              metadata: Mapping[str, Mapping[str, str]] | None = None) -> Path:
    """Write ``messages`` (in the given order) with palpa's channel conventions and finish the file."""
    w = BagWriter(path, chunk_size=chunk_size, overwrite=True)
    schemas: dict[str, int] = {}
    channels: dict[tuple[str, str, str, bool], int] = {}
    for name, data in (metadata or {}).items():
        w.add_metadata(name, data)
    for m in messages:
        if m.type not in schemas:
            raw = schema_bytes(m.type)
            schemas[m.type] = w.register_schema(m.type, SCHEMA_ENCODING, raw) if raw else 0
        key = (m.topic, m.node, m.type, m.latched)
        if key not in channels:
            channels[key] = w.register_channel(m.topic, MESSAGE_ENCODING, schemas[m.type], {
                META_TYPE: m.type, META_PUBLISHER: m.node, META_LATCHED: "true" if m.latched else "false"})
        w.add_message(channels[key], m.log_time, m.log_time if m.publish_time is None else m.publish_time,
                      m.seq, m.payload)
    w.finish()
    return Path(path)


@dataclass
class OfficialView:
    """What the official reader found in one file."""

    messages: list[tuple[str, int, int, int, bytes]] = field(default_factory=list)
    """(topic, sequence, log_time, publish_time, data) in log-time order."""
    channels: dict[int, Any] = field(default_factory=dict)
    schemas: dict[int, Any] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    statistics: Any = None

    def topic(self, name: str) -> list[bytes]:
        return [m[4] for m in self.messages if m[0] == name]


def check_official(path: str | os.PathLike[str]) -> OfficialView:
    """Read ``path`` with ``mcap.reader`` (indexed and streaming, CRCs on); raise AssertionError if it disagrees
    with itself or has no summary. Metadata records of the same name: the last one wins."""
    data = Path(path).read_bytes()
    view = OfficialView()
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        raise AssertionError(f"{path}: no summary section / statistics")
    view.channels = dict(summary.channels)
    view.schemas = dict(summary.schemas)
    view.statistics = summary.statistics
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        if channel.schema_id and schema is None:
            raise AssertionError(f"{path}: channel {channel.topic} has no schema record")
        view.messages.append((channel.topic, message.sequence, message.log_time, message.publish_time,
                              message.data))
    for md in reader.iter_metadata():
        view.metadata[md.name] = md.metadata
    for att in reader.iter_attachments():
        view.attachments[att.name] = att.data
    if len(view.messages) != summary.statistics.message_count:
        raise AssertionError(f"{path}: {len(view.messages)} messages read, statistics say "
                             f"{summary.statistics.message_count}")
    streamed = sum(1 for _ in NonSeekingReader(io.BytesIO(data), validate_crcs=True).iter_messages(
        log_time_order=False))
    if streamed != len(view.messages):
        raise AssertionError(f"{path}: streaming reader saw {streamed} messages, indexed reader {len(view.messages)}")
    for sid, schema in view.schemas.items():
        if schema.encoding == SCHEMA_ENCODING:
            json.loads(schema.data)  # must be JSON
        if sid == 0:
            raise AssertionError(f"{path}: schema id 0 is reserved")
    return view


def play_in_memory(params: Mapping[str, object]) -> tuple[Player, list[RawMessage]]:
    """Run the Player node with ``params`` (``file`` and the rest of ``palpa play``'s; ``exit_delay_s`` 0 unless
    given) on a :class:`~palpa.testing.MemoryBus` until it is done; returns it (exit code, lateness) and every
    message it sent, as a subscriber of every topic received them."""
    from palpa.node.node import Node
    from palpa.record.player import Player
    from palpa.testing import MemoryBus

    bus = MemoryBus()
    got: list[RawMessage] = []
    probe = Node(name="probe", transport=bus.transport(), heartbeat_s=0)
    probe.subscribe_raw("", got.append)
    player = Player(name="player", params={"exit_delay_s": 0.0, **params}, transport=bus.transport(), heartbeat_s=0)
    try:
        player.spin()
        probe.spin_once(0)
    finally:
        player.close(0)
        probe.close(0)
    return player, got
