"""The ``(msg, info)`` callback form: the header and blobs of that very message, single or batched."""

from __future__ import annotations

import palpa
from messages import Text
from palpa.testing import GraphHarness


class Burst(palpa.Node):
    """Publishes three texts from one timer callback: they leave as one batch."""

    def setup(self) -> None:
        self.out = self.publisher("chatter", Text)
        self.timer(0.1, self.tick, oneshot=True)

    def tick(self) -> None:
        for word in ("a", "b", "c"):
            self.out.publish(Text(text=word))


class Reader(palpa.Node):
    def setup(self) -> None:
        self.got: list[tuple[str, str, int, list[bytes], bool]] = []
        self.plain: list[str] = []
        self.subscribe("chatter", self.on_text)
        self.subscribe("image", self.on_plain)

    def on_text(self, msg: Text, info: palpa.MsgInfo) -> None:
        self.got.append((msg.text, info.header.node, info.header.seq, info.blobs, info.from_cache))

    def on_plain(self, msg: Text) -> None:
        self.plain.append(msg.text)


def test_a_callback_asking_for_info_gets_each_messages_own_header_and_blobs() -> None:
    with GraphHarness() as g:
        reader = g.add(Reader, name="reader")
        g.add(Burst, name="burst")
        g.advance(0.2)  # the batch of three: each with its own sequence number
        assert reader.got == [("a", "burst", 1, [], False), ("b", "burst", 2, [], False), ("c", "burst", 3, [], False)]
        g.publish("chatter", Text(text="with blobs"), blobs=[b"\x00\x01", b"\x02"])
        text, node, seq, blobs, cached = reader.got[-1]
        assert (text, blobs, cached) == ("with blobs", [b"\x00\x01", b"\x02"], False) and seq == 1 and node != "burst"
        g.publish("image", Text(text="plain"))  # the one-argument form is unchanged
        assert reader.plain == ["plain"]
        assert reader.handler_errors == 0
