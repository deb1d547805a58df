"""Batches on the wire (docs/wire.md): [topic, array of headers, array of payloads], decoded in one call when the
batch is the common one, message by message when it is not, with the same counters either way."""

from __future__ import annotations

import msgpack
import msgspec
import pytest

import palpa
from messages import Text
from nodes.demo import Listener
from palpa.net.wire import Header, HeaderTemplate, msgpack_array, split_envelope
from palpa.testing import GraphHarness, NodeHarness


def batch(topic: bytes, items: list[tuple[str, int, str, object]]) -> list[bytes]:
    """A batch envelope from (type, seq, node, payload object) tuples, packed by hand as a foreign client would."""
    headers = [msgpack.packb({"type": t, "seq": s, "stamp": 1, "node": n}) for t, s, n, _ in items]
    return [topic, msgpack_array(headers), msgpack_array([msgpack.packb(p) for *_, p in items])]


class Recorder(palpa.Node):
    def setup(self) -> None:
        self.texts: list[str] = []
        self.raw: list[tuple[int, bytes]] = []
        self.subscribe("chatter", self.on_text)
        self.subscribe_raw("chat", lambda m: self.raw.append((m.header.seq, m.payload)))

    def on_text(self, msg: Text) -> None:
        if msg.text == "boom":
            raise RuntimeError("boom")
        self.texts.append(msg.text)


@pytest.mark.parametrize("n", [1, 15, 16, 64, 70_000])
def test_msgpack_array_is_plain_msgpack(n: int) -> None:
    items = [msgpack.packb(i) for i in range(n)]
    assert msgpack.unpackb(msgpack_array(items)) == list(range(n))


def test_published_batch_is_three_frames_any_plain_msgpack_reader_can_read() -> None:
    tpl = HeaderTemplate("Text", "talker", False)
    frames = [b"chatter", msgpack_array([tpl.pack(i, 10 * i) for i in (1, 2, 3)]),
              msgpack_array([msgspec.msgpack.encode(Text(text=str(i))) for i in (1, 2, 3)])]
    assert [h["seq"] for h in msgpack.unpackb(frames[1])] == [1, 2, 3]
    assert [p["text"] for p in msgpack.unpackb(frames[2])] == ["1", "2", "3"]
    items = split_envelope(frames)
    assert [(h.seq, msgpack.unpackb(p)["text"]) for h, p, _ in items] == [(1, "1"), (2, "2"), (3, "3")]


def test_node_publishes_bursts_as_batches_that_arrive_whole_and_in_order() -> None:
    class Burst(palpa.Node):
        def setup(self) -> None:
            self.out = self.publisher("chatter", Text)
            self.subscribe("go", self.on_go)

        def on_go(self, msg: Text) -> None:
            for i in range(150):
                self.out.publish(Text(text=str(i)))

    g = GraphHarness()
    burst = g.add(Burst, name="burst")
    rec = g.add(Recorder)
    g.publish("go", Text(text="now"))
    assert rec.texts == [str(i) for i in range(150)]
    assert [s for s, _ in rec.raw] == list(range(1, 151))
    assert burst.out.seq == 150
    stats = rec.counters()["chatter"]
    assert (stats.received, stats.gaps, stats.decode_errors) == (150, 0, 0)


def test_a_bad_payload_in_a_batch_costs_that_message_only() -> None:
    h = NodeHarness(Recorder)
    h.publish_raw(batch(b"chatter", [("Text", 1, "x", {"text": "a"}), ("Text", 2, "x", {"text": 7}),
                                     ("Text", 3, "x", {"text": "c"})]))
    stats = h.node.counters()["chatter"]
    assert h.node.texts == ["a", "c"]
    # sequence numbers count valid messages only (garbage cannot fake gaps): the bad one is an error and a gap
    assert (stats.received, stats.decode_errors, stats.gaps) == (2, 1, 1)
    assert "at `$.text`" in stats.last_error


def test_a_failing_callback_in_a_batch_does_not_lose_the_rest() -> None:
    h = NodeHarness(Recorder)
    h.publish_raw(batch(b"chatter", [("Text", i, "x", {"text": t}) for i, t in
                                     enumerate(["a", "boom", "b", "boom", "c"], 1)]))
    assert h.node.texts == ["a", "b", "c"]
    assert h.node.handler_errors == 2


def test_gaps_repeats_mixed_types_and_publishers_are_counted_as_single_messages_would_be() -> None:
    h = NodeHarness(Recorder)
    h.publish_raw(batch(b"chatter", [("Text", 1, "x", {"text": "1"}), ("Text", 2, "x", {"text": "2"})]))
    # starts after a gap of 2
    h.publish_raw(batch(b"chatter", [("Text", 5, "x", {"text": "5"}), ("Text", 6, "x", {"text": "6"})]))
    # repeats the last one (a duplicate) and carries a message of the wrong type
    h.publish_raw(batch(b"chatter", [("Text", 6, "x", {"text": "dup"}), ("RobotPose", 7, "x", {"x": 1}),
                                     ("Text", 8, "x", {"text": "8"})]))
    # two publishers in one batch (a foreign client may do this)
    h.publish_raw(batch(b"chatter", [("Text", 9, "x", {"text": "9"}), ("Text", 1, "y", {"text": "y1"})]))
    stats = h.node.counters()["chatter"]
    assert h.node.texts == ["1", "2", "5", "6", "8", "9", "y1"]
    assert (stats.gaps, stats.duplicates, stats.decode_errors) == (3, 1, 1)  # the wrong-typed 7 is a gap too
    assert stats.received == 7 and "expected type Text, got RobotPose" in stats.last_error


@pytest.mark.parametrize("frames, error", [
    ([b"chatter", msgpack_array([msgpack.packb({"type": "Text", "seq": 1, "stamp": 1, "node": "x"})] * 2),
      msgpack_array([msgpack.packb({"text": "one"})])], "batch header lists 2 messages but 1 payloads follow"),
    ([b"chatter", msgpack_array([msgpack.packb({"type": "Text", "seq": 1, "stamp": 1, "node": "x"})]),
      msgpack.packb({"text": "not an array"})], "bad batch payload array"),
    ([b"chatter", msgpack_array([msgpack.packb({"type": "Text", "seq": 1, "stamp": 1, "node": "x"})]),
      msgpack_array([msgpack.packb({"text": "a"})]), b"extra"], "batch envelope has 4 frames, expected 3"),
    ([b"chatter", msgpack.packb([{"type": "Text"}]), msgpack_array([])], "bad batch header"),
])
def test_malformed_batches_are_counted_with_what_was_wrong(frames: list[bytes], error: str) -> None:
    h = NodeHarness(Listener)
    h.publish_raw(frames)
    stats = h.node.counters()["chatter"]
    assert stats.decode_errors == 1 and error in stats.last_error
    h.publish("chatter", Text(text="still alive"))
    assert h.node.heard == 1


def test_iterator_subscription_receives_a_batch_in_order() -> None:
    g = GraphHarness()
    script = g.add(palpa.Node, name="script")
    sub = script.subscribe("chatter", Text)
    g.publish_raw(batch(b"chatter", [("Text", i, "x", {"text": str(i)}) for i in range(1, 40)]))
    assert [m.text for m in sub.queue] == [str(i) for i in range(1, 40)]
    assert sub.last_header is not None and sub.last_header.seq == 39


def test_header_decodes_as_the_documented_struct() -> None:
    frames = batch(b"t", [("Text", 3, "n", {"text": "x"})])
    (header, payload, blobs), = split_envelope(frames)
    assert header == Header(type="Text", seq=3, stamp=1, node="n") and blobs == []
    assert msgpack.unpackb(payload) == {"text": "x"}
