"""The envelope every message travels in (documented for other languages in docs/wire.md).

A message is one ZeroMQ multipart message::

    frame 0  topic    UTF-8 bytes, e.g. b"probe/heights"       (what ZeroMQ filters on, by prefix)
    frame 1  header   msgpack map {"type": str, "seq": uint64, "stamp": uint64 ns, "node": str[, "latched": true]}
    frame 2  payload  msgpack map of the message's fields (plain ``msgpack.unpackb`` reads it)
    frame 3+ blobs    optional raw binary attachments (e.g. a debug image), never msgpack-encoded

A *batch* carries several messages of one topic, from one publisher, in one ZeroMQ message (a publisher under
load coalesces them)::

    frame 0  topic
    frame 1  msgpack ARRAY of n header maps
    frame 2  msgpack ARRAY of the n payloads, in order (a batch has no blobs)

A receiver tells the two apart by frame 1's first byte (a msgpack map vs an array). Three frames whatever n is:
with pyzmq every frame costs a receiver microseconds, and one array decodes in a single call.
ZeroMQ subscriptions match by prefix, so a receiver compares frame 0 to its topic exactly before decoding.
``seq`` counts from 1 per (publisher node, topic); receivers count gaps to make high-water-mark drops visible.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass, field
from typing import Annotated, Any

import msgspec

from palpa.errors import DecodeError

__all__ = [
    "COUNTER_MAX",
    "Envelope",
    "MAX_BATCH",
    "MAX_MSG_BYTES",
    "MAX_TOPIC_BYTES",
    "WIRE_VERSION",
    "Header",
    "HeaderTemplate",
    "SequenceTracker",
    "TopicStats",
    "decode_header",
    "encode_header",
    "msgpack_array",
    "parse_envelope",
    "split_batch",
    "split_envelope",
    "uint64",
]


_UINT64 = Annotated[int, msgspec.Meta(ge=0)]  # msgpack holds nothing above uint64

MAX_MSG_BYTES = 16 * 2**20
"""Default limit on one message (per bus: ZeroMQ's MAXMSGSIZE on its inputs; per node: ``max_msg_bytes``)."""
MAX_TOPIC_BYTES = 1024
MAX_BATCH = 10_000
"""Messages one batch may carry; palpa's publishers send at most DEFAULT_BATCH (64)."""

COUNTER_MAX = 2**63 - 1
"""Receive counters saturate here: any msgpack reader (int64 or uint64) reads them, and no bytes a peer sends
can push a counter past what a heartbeat encodes."""


class Header(msgspec.Struct, frozen=True, omit_defaults=True, gc=False):
    """Frame 1 of the envelope. ``stamp`` is the publish time in ns since the Unix epoch."""

    type: str
    seq: _UINT64
    stamp: int
    node: str
    latched: bool = False
    inc: _UINT64 = 0
    """The publisher's incarnation: a number drawn anew each time a node starts (0: not given, as from older
    publishers). A change means the publisher restarted, so its ``seq`` starting again at 1 is news, not a
    duplicate."""
    at: _UINT64 = 0
    """The simulated instant (ns) the publisher was at, from a node following a simulation clock (0: a node on the
    wall clock, or not given). Under the event lockstep a node gets clock ticks only at its own timers' deadlines
    and takes the time of any other instant from the messages it handles there (palpa.timing.simclock)."""


_header_encoder = msgspec.msgpack.Encoder()
_header_decoder = msgspec.msgpack.Decoder(Header)
_batch_decoder = msgspec.msgpack.Decoder(list[Header])
_raw_items_decoder = msgspec.msgpack.Decoder(list[msgspec.Raw])


WIRE_VERSION = 2
"""The wire protocol's version (docs/wire.md, *Versions*); nodes state it in their heartbeats. 2: every integer of
a header is a msgpack uint64, the latch cache takes ``UNWATCH``, ``ERR`` reasons are plain text."""

_U64 = struct.Struct(">BQ")
_SEQ_STAMP = struct.Struct(">4sBQ6sBQ").pack   # "seq", uint64, "stamp", uint64: one call for the hot part


def uint64(value: int, what: str) -> bytes:
    """``value`` as a msgpack uint64 (``0xcf`` and 8 bytes), the one width every header integer has on the wire, so
    that a reader typing integers by their width (JavaScript's BigInt for 64-bit ones) sees one type per field."""
    if not 0 <= value < 2**64:
        raise ValueError(f"header {what} {value} is not a uint64")
    return _U64.pack(0xCF, value)


def encode_header(header: Header) -> bytes:
    """Serialise a header to its msgpack map (its integers as uint64, whatever their size: docs/wire.md)."""
    h, enc = header, _header_encoder.encode
    try:
        out = (bytes((0x84 + h.latched + bool(h.inc) + bool(h.at),)) + b"\xa4type" + enc(h.type)
               + _SEQ_STAMP(b"\xa3seq", 0xCF, h.seq, b"\xa5stamp", 0xCF, h.stamp) + b"\xa4node" + enc(h.node))
    except struct.error:
        raise ValueError(f"header seq {h.seq} or stamp {h.stamp} is not a uint64") from None
    if h.latched:
        out += b"\xa7latched\xc3"
    if h.inc:
        out += b"\xa3inc" + uint64(h.inc, "inc")
    if h.at:
        out += b"\xa2at" + uint64(h.at, "at")
    return out


def decode_header(frame: bytes) -> Header:
    """Parse frame 1; raises :class:`DecodeError` naming the problem when it is not a valid header."""
    try:
        return _header_decoder.decode(frame)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise DecodeError(f"bad envelope header: {exc}") from None


class HeaderTemplate:
    """Fast header encoding for one publisher: the constant fields are packed once, ``seq`` and ``stamp`` per
    message (as msgpack uint64, valid for every msgpack reader)."""

    def __init__(self, type_name: str, node: str, latched: bool, inc: int = 0, instant: bool = False) -> None:
        enc = msgspec.msgpack.encode
        entries = 4 + bool(latched) + bool(inc) + bool(instant)
        prefix = (
            bytes([0x80 | entries]) + enc("type") + enc(type_name) + enc("node") + enc(node)
            + (enc("latched") + enc(True) if latched else b"") + (enc("inc") + uint64(inc, "inc") if inc else b"")
            + enc("seq") + b"\xcf"
        )
        mid = enc("stamp") + b"\xcf"
        # the whole map in one struct: the constant parts as fixed-length byte strings, the numbers as uint64
        fmt = f">{len(prefix)}sQ{len(mid)}sQ"
        self._last = enc("at") + b"\xcf" if instant else b""
        if instant:
            fmt += f"{len(self._last)}sQ"
        self._pack = functools.partial(struct.Struct(fmt).pack, prefix)
        self._mid = mid

    def pack(self, seq: int, stamp_ns: int, at_ns: int = 0) -> bytes:
        """The header map of one message (``at_ns``: the publisher's simulated instant, with ``instant``)."""
        if self._last:
            return self._pack(seq, self._mid, stamp_ns, self._last, at_ns)
        return self._pack(seq, self._mid, stamp_ns)


def msgpack_array(items: list[bytes]) -> bytes:
    """A msgpack array of already-encoded items (frames 1 and 2 of a batch)."""
    n = len(items)
    if n < 16:
        prefix = bytes([0x90 | n])
    elif n < 0x10000:
        prefix = b"\xdc" + n.to_bytes(2, "big")
    else:
        prefix = b"\xdd" + n.to_bytes(4, "big")
    return prefix + b"".join(items)


class Envelope(msgspec.Struct, frozen=True, gc=False):
    """A parsed envelope: one header per message; ``payload`` is the message's payload, or for a batch the
    msgpack array of every payload (see :func:`split_batch`)."""

    headers: list[Header]
    payload: bytes
    blobs: list[bytes]
    batch: bool

    def messages(self) -> list[tuple[Header, bytes, list[bytes]]]:
        """(header, payload, blobs) of each message; raises :class:`DecodeError` for a malformed batch."""
        if not self.batch:
            return [(self.headers[0], self.payload, self.blobs)]
        return [(h, p, []) for h, p in zip(self.headers, split_batch(self), strict=True)]


def parse_envelope(frames: list[bytes]) -> Envelope:
    """Validate the frame count and the header(s); raises :class:`DecodeError` saying what is wrong."""
    if len(frames) < 3:
        raise DecodeError(f"envelope has {len(frames)} frames, expected at least 3")
    if len(frames[0]) > MAX_TOPIC_BYTES:
        raise DecodeError(f"topic of {len(frames[0])} bytes (at most {MAX_TOPIC_BYTES})")
    head = frames[1]
    kind = head[0] if head else 0
    if kind & 0xF0 == 0x90 or kind == 0xDC or kind == 0xDD:  # a msgpack array: a batch
        try:
            headers = _batch_decoder.decode(head)
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            raise DecodeError(f"bad batch header: {exc}") from None
        if not headers or len(headers) > MAX_BATCH:
            raise DecodeError(f"batch of {len(headers)} messages (1..{MAX_BATCH})")
        if len(frames) != 3:
            raise DecodeError(f"batch envelope has {len(frames)} frames, expected 3")
        return Envelope(headers, frames[2], [], True)
    return Envelope([decode_header(head)], frames[2], frames[3:], False)


def split_batch(envelope: Envelope) -> list[bytes]:
    """The payload bytes of each message of a batch (each a complete msgpack object)."""
    try:
        items = _raw_items_decoder.decode(envelope.payload)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise DecodeError(f"bad batch payload array: {exc}") from None
    if len(items) != len(envelope.headers):
        raise DecodeError(f"batch header lists {len(envelope.headers)} messages but {len(items)} payloads follow")
    return [bytes(item) for item in items]


def split_envelope(frames: list[bytes]) -> list[tuple[Header, bytes, list[bytes]]]:
    """(header, payload, blobs) for each message in an envelope, single or batch.

    Raises :class:`DecodeError` saying what is wrong with a malformed envelope.
    """
    return parse_envelope(frames).messages()


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

    def loss(self) -> str:
        """What a consumer that must hold every message lacks, in words ('' when nothing): messages missing by
        their sequence numbers, and publisher restarts (what it held before is gone)."""
        if not (self.gaps or self.restarts):
            return ""
        return f"lost {self.gaps} message(s) and its publisher restarted {self.restarts} time(s)"

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
    _inc: dict[tuple[str, str], int] = field(default_factory=dict)
    """The incarnation last seen per (topic, publisher), where one was given."""

    def observe(self, topic: str, node: str, seq: int, stats: TopicStats, inc: int = 0) -> bool:
        """Record one arrival; returns False when it is a duplicate that should be dropped.

        A latched message can reach a late joiner twice (live and from the bus cache); an exact repeat of the
        last sequence number from the same incarnation of the same publisher is that case. A new incarnation is
        a restart whatever its sequence number.
        """
        key = (topic, node)
        last = self._last.get(key)
        if self._inc.get(key, 0) != inc:
            self._inc[key] = inc
            if last is not None:
                stats.restarts = min(COUNTER_MAX, stats.restarts + 1)
                last = None
        if last is not None:
            if seq == last:
                stats.duplicates = min(COUNTER_MAX, stats.duplicates + 1)
                return False
            if seq < last:
                stats.restarts = min(COUNTER_MAX, stats.restarts + 1)
            elif seq > last + 1:
                stats.gaps = min(COUNTER_MAX, stats.gaps + seq - last - 1)
        self._last[key] = seq
        stats.received += 1
        return True

    def observe_run(self, topic: str, node: str, first: int, n: int, stats: TopicStats, inc: int = 0) -> bool:
        """Record ``n`` arrivals with consecutive sequence numbers from ``first`` (a batch) in one step; returns
        False, recording nothing, when the run does not start after the last one seen or comes from another
        incarnation (the caller then goes message by message)."""
        key = (topic, node)
        last = self._last.get(key)
        if self._inc.get(key, 0) != inc:
            if last is not None:
                return False
            self._inc[key] = inc
        if last is not None:
            if first <= last:
                return False
            stats.gaps = min(COUNTER_MAX, stats.gaps + first - last - 1)
        self._last[key] = first + n - 1
        stats.received += n
        return True

    def seen_at_least(self, topic: str, node: str, seq: int, inc: int = 0) -> bool:
        """True when a message with this or a later sequence number from this incarnation of ``node`` was
        already delivered."""
        key = (topic, node)
        last = self._last.get(key)
        return last is not None and last >= seq and self._inc.get(key, 0) == inc

