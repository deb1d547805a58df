"""Fuzzing the latch protocol and the recorder at their extremes (issue 39): nesting around MAX_NESTING and far past
it, sizes, stamps and sequence numbers at the ends of their ranges. The bus's latch handling never raises and
keeps its bounds; every SET is cached or refused with an ERR and counted; the recorder stays up, its index is true
(read back with the official ``mcap`` reader) and every message is recorded or refused-and-counted. In process:
the latch handler is driven with a stand-in for its ROUTER socket, the recorder through a NodeHarness."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import msgpack
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from palpa.net.bus import Bus
from palpa.net.latch import MAX_WATCHES
from palpa.net.wire import MAX_NESTING
from palpa.record.recorder import Recorder
from palpa.record.testing import check_official
from palpa.testing import NodeHarness
from tests.procs import bus_spec

U64 = 2**64 - 1
I64_MIN = -(2**63)
SEQS = st.sampled_from([0, 1, 2, 2**32 - 1, 2**32, 2**32 + 1, 2**63 - 1, 2**63, U64]) | st.integers(0, U64)
STAMPS = st.sampled_from([I64_MIN, -1, 0, 1, 2**63 - 1, 2**63, U64]) | st.integers(I64_MIN, U64)


@st.composite
def nested_value(draw: st.DrawFn) -> bytes:
    """A msgpack value nested about the limit, far past it, or not at all; arrays, maps or both."""
    depth = draw(st.sampled_from([0, 1, MAX_NESTING - 1, MAX_NESTING, MAX_NESTING + 1, 1000, 5000]))
    kinds = draw(st.lists(st.sampled_from([b"\x91", b"\x81\xa1k"]), min_size=1, max_size=3))
    leaf = draw(st.sampled_from([b"\x01", b"\x90", b"\x80", b"\xc0", b"\xa0"]))
    return b"".join(kinds[i % len(kinds)] for i in range(depth)) + leaf


@st.composite
def payload(draw: st.DrawFn) -> bytes:
    """A message payload: a well-formed map, a nested field, a large value, or garbage."""
    kind = draw(st.sampled_from(["text", "nested", "big", "garbage", "empty"]))
    if kind == "text":
        return bytes(msgpack.packb({"text": draw(st.text(max_size=20))}))
    if kind == "nested":
        return b"\x81\xa4text" + draw(nested_value())
    if kind == "big":
        return bytes(msgpack.packb({"text": "x" * draw(st.sampled_from([0, 1, 2**16, 2**20]))}))
    if kind == "garbage":
        return draw(st.binary(max_size=64))
    return b""


@st.composite
def header(draw: st.DrawFn) -> bytes:
    """An envelope header with extreme numbers, maybe a deep unknown field, or garbage."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=32))
    fields: dict[str, Any] = {"type": draw(st.sampled_from(["Text", "NoSuchType"])), "seq": draw(SEQS),
                              "stamp": draw(STAMPS), "node": draw(st.sampled_from(["a", "b", "\x00", "n" * 300])),
                              "latched": draw(st.booleans())}
    packed = bytes(msgpack.packb(fields))
    if draw(st.booleans()):
        packed = bytes([packed[0] + 1]) + packed[1:] + b"\xa5extra" + draw(nested_value())
    return packed


TOPICS = st.sampled_from([b"", b"a", b"a/b", b"cal/x", b"_palpa/curve/keys", b"t" * 1025])


class FakeRouter:
    """What the latch handler sends, instead of a ROUTER socket."""

    def __init__(self) -> None:
        self.sent: list[list[bytes]] = []

    def send_multipart(self, frames: list[bytes], flags: int = 0) -> None:
        self.sent.append(frames)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from([b"SET", b"GET", b"PING", b"NOPE"]), TOPICS, header(), payload()),
                min_size=1, max_size=12))
def test_latch_protocol_fuzz(requests: list[tuple[bytes, bytes, bytes, bytes]]) -> None:
    bus = Bus(bus_spec("ipc"), latch_max_entries=4, latch_max_bytes=2**20 + 4096)  # never started: no sockets
    try:
        router = FakeRouter()
        for n, (verb, topic, head, body) in enumerate(requests):
            ident = b"client-%d" % (n % 3)
            before_refused, before_sent = bus.latch_refused, len(router.sent)
            bus._handle_latch(router, [ident, verb, topic, head, body])  # raises nothing, whatever the input
            cache = bus._cache
            assert len(cache.values) <= 4 and cache.table.bytes <= 2**20 + 4096 and len(bus._watchers) <= MAX_WATCHES
            if verb == b"SET":
                stored = cache.values.get(topic) == [head, body]
                refused = bus.latch_refused == before_refused + 1
                assert stored != refused  # cached, or refused and counted
                if refused:
                    assert router.sent[before_sent][:3] == [ident, b"ERR", topic[:1024]]
        assert bus.internal_errors == 0
    finally:
        bus.stop()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(["chatter", "cal/x", "b" * 200]), header(), payload(),
                          st.sampled_from([(), (b"blob",)])), min_size=1, max_size=15))
def test_recorder_fuzz(messages: list[tuple[str, bytes, bytes, tuple[bytes, ...]]]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.mcap"
        h = NodeHarness(Recorder, {"output": str(out)})
        rec = h.node
        for topic, head, body, blobs in messages:
            h.publish_raw([topic.encode(), head, body, *blobs])
        assert not rec._failed
        counters = {t: s for t, s in rec.counters().items() if not t.startswith("_palpa/")}
        h.close()
        view = check_official(out)  # the index is true: statistics == messages read, indexed and streamed
        recorded = sum(1 for m in view.messages if not m[0].startswith("_palpa/"))
        # every message: recorded, refused (counted), a malformed envelope (counted) or a duplicate (counted)
        refused = sum(rec.refused.get(k, 0) for k in ("stamp_out_of_range", "channel_limit"))
        dropped = sum(s.duplicates for s in counters.values())
        malformed = sum(1 for _t, head, _b, _bl in messages if not _parses(head))
        assert recorded + refused + dropped + malformed == len(messages)


def _parses(head: bytes) -> bool:
    from palpa.errors import DecodeError
    from palpa.net.wire import decode_header

    try:
        decode_header(head)
    except DecodeError:
        return False
    return True
