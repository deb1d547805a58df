"""The envelope every message travels in (documented for other languages in docs/wire.md).

A message is one ZeroMQ multipart message::

    frame 0  topic    UTF-8 bytes, e.g. b"probe/heights"       (what ZeroMQ filters on, by prefix)
    frame 1  header   msgpack map {"type": str, "seq": int, "stamp": int ns, "node": str[, "latched": true]}
    frame 2  payload  msgpack map of the message's fields (plain ``msgpack.unpackb`` reads it)
    frame 3+ blobs    optional raw binary attachments (e.g. a debug image), never msgpack-encoded

ZeroMQ subscriptions match by prefix, so a receiver compares frame 0 to its topic exactly before decoding.
``seq`` counts from 1 per (publisher node, topic); receivers count gaps to make high-water-mark drops visible.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import msgspec

from palpa.errors import DecodeError

__all__ = [
    "Header",
    "SequenceTracker",
    "TopicStats",
    "decode_header",
    "encode_header",
]


class Header(msgspec.Struct, frozen=True, omit_defaults=True):
    """Frame 1 of the envelope. ``stamp`` is the publish time in ns since the Unix epoch."""

    type: str
    seq: int
    stamp: int
    node: str
    latched: bool = False


_header_encoder = msgspec.msgpack.Encoder()
_header_decoder = msgspec.msgpack.Decoder(Header)


def encode_header(header: Header) -> bytes:
    """Serialise a header to its msgpack map."""
    return _header_encoder.encode(header)


def decode_header(frame: bytes) -> Header:
    """Parse frame 1; raises :class:`DecodeError` naming the problem when it is not a valid header."""
    try:
        return _header_decoder.decode(frame)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise DecodeError(f"bad envelope header: {exc}") from None


@dataclass
class TopicStats:
    """Per-topic receive counters, as a subscriber (or the recorder, or ``topic hz``) sees them."""

    received: int = 0
    gaps: int = 0
    """Messages missing according to sequence numbers (dropped at a high-water mark, or lost to a slow join)."""
    duplicates: int = 0
    restarts: int = 0
    """A publisher's sequence went backwards: it restarted (or a recording looped)."""
    decode_errors: int = 0
    last_error: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "received": self.received,
            "gaps": self.gaps,
            "duplicates": self.duplicates,
            "restarts": self.restarts,
            "decode_errors": self.decode_errors,
        }


@dataclass
class SequenceTracker:
    """Tracks the last sequence number per (topic, publisher) and classifies each arrival."""

    _last: dict[tuple[str, str], int] = field(default_factory=dict)

    def observe(self, topic: str, node: str, seq: int, stats: TopicStats) -> bool:
        """Record one arrival; returns False when it is a duplicate that should be dropped.

        A latched message can reach a late joiner twice (live and from the bus cache); an exact repeat of the
        last sequence number from the same publisher is that case.
        """
        key = (topic, node)
        last = self._last.get(key)
        if last is not None:
            if seq == last:
                stats.duplicates += 1
                return False
            if seq < last:
                stats.restarts += 1
            elif seq > last + 1:
                stats.gaps += seq - last - 1
        self._last[key] = seq
        stats.received += 1
        return True

    def seen_at_least(self, topic: str, node: str, seq: int) -> bool:
        """True when a message with this or a later sequence number from ``node`` was already delivered."""
        last = self._last.get((topic, node))
        return last is not None and last >= seq

