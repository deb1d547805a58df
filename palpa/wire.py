"""The envelope every message travels in (documented for other languages in docs/wire.md).

A message is one ZeroMQ multipart message::

    frame 0  topic    UTF-8 bytes, e.g. b"probe/heights"       (what ZeroMQ filters on, by prefix)
    frame 1  header   msgpack map {"type": str, "seq": int, "stamp": int ns, "node": str[, "latched": true]}
    frame 2  payload  msgpack map of the message's fields (plain ``msgpack.unpackb`` reads it)
    frame 3+ blobs    optional raw binary attachments (e.g. a debug image), never msgpack-encoded

A *batch* carries several messages of one topic in one ZeroMQ message (a publisher under load coalesces them)::

    frame 0  topic
    frame 1  msgpack ARRAY of n header maps
    frame 2..n+1  the n payloads, in order (a batch has no blobs)

A receiver tells the two apart by frame 1's first byte (a msgpack map vs an array).
ZeroMQ subscriptions match by prefix, so a receiver compares frame 0 to its topic exactly before decoding.
``seq`` counts from 1 per (publisher node, topic); receivers count gaps to make high-water-mark drops visible.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

import msgspec

from palpa.errors import DecodeError

__all__ = [
    "Header",
    "HeaderTemplate",
    "SequenceTracker",
    "TopicStats",
    "decode_header",
    "encode_batch_header",
    "encode_header",
    "split_envelope",
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
_batch_decoder = msgspec.msgpack.Decoder(list[Header])


def encode_header(header: Header) -> bytes:
    """Serialise a header to its msgpack map."""
    return _header_encoder.encode(header)


def decode_header(frame: bytes) -> Header:
    """Parse frame 1; raises :class:`DecodeError` naming the problem when it is not a valid header."""
    try:
        return _header_decoder.decode(frame)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise DecodeError(f"bad envelope header: {exc}") from None


def encode_batch_header(headers: list[Header]) -> bytes:
    """Serialise the headers of a batch (frame 1 of a batch envelope)."""
    return _header_encoder.encode(headers)


class HeaderTemplate:
    """Fast header encoding for one publisher: the constant fields are packed once, ``seq`` and ``stamp`` per
    message (as msgpack uint64, valid for every msgpack reader)."""

    _tail = struct.Struct(">Q7sQ")

    def __init__(self, type_name: str, node: str, latched: bool) -> None:
        enc = msgspec.msgpack.encode
        entries = 5 if latched else 4
        self._prefix = (
            bytes([0x80 | entries]) + enc("type") + enc(type_name) + enc("node") + enc(node)
            + (enc("latched") + enc(True) if latched else b"") + enc("seq") + b"\xcf"
        )
        self._mid = enc("stamp") + b"\xcf"

    def pack(self, seq: int, stamp_ns: int) -> bytes:
        """The header map of one message."""
        return self._prefix + self._tail.pack(seq, self._mid, stamp_ns)

    @staticmethod
    def pack_batch(headers: list[bytes]) -> bytes:
        """Frame 1 of a batch from packed single headers (msgpack array 16)."""
        return b"\xdc" + len(headers).to_bytes(2, "big") + b"".join(headers)


def split_envelope(frames: list[bytes]) -> list[tuple[Header, bytes, list[bytes]]]:
    """(header, payload, blobs) for each message in an envelope, single or batch.

    Raises :class:`DecodeError` saying what is wrong with a malformed envelope.
    """
    if len(frames) < 3:
        raise DecodeError(f"envelope has {len(frames)} frames, expected at least 3")
    first = frames[1][:1]
    if first and (0x90 <= first[0] <= 0x9F or first[0] in (0xDC, 0xDD)):
        try:
            headers = _batch_decoder.decode(frames[1])
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            raise DecodeError(f"bad batch header: {exc}") from None
        if len(headers) != len(frames) - 2:
            raise DecodeError(f"batch header lists {len(headers)} messages but {len(frames) - 2} payloads follow")
        return [(h, frames[2 + i], []) for i, h in enumerate(headers)]
    return [(decode_header(frames[1]), frames[2], frames[3:])]


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

