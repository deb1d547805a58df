"""Limits a hostile or clumsy client runs into (issue 22): message size per bus and per node, the latched-value
cache's validation and bounds, graph-latched topics cached with no subscriber, truncated log lines, and recordings
that flag malformed payloads and print names safely."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import msgpack
import msgspec
import pytest
import zmq

import palpa
from messages import Text
from palpa.cli.main import main
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.net.transport import TransportOptions, ZmqTransport
from palpa.node.node import LOG_TEXT_MAX
from palpa.record.format import MD_DROPS
from palpa.record.recorder import Recorder
from palpa.record.testing import check_official
from palpa.runtime_msgs import LogRecord
from palpa.testing import NodeHarness
from tests.procs import bus_spec, wait_until


def header(seq: int, node: str = "evil", type_: str = "Text", latched: bool = False) -> bytes:
    h: dict[str, object] = {"type": type_, "seq": seq, "stamp": 1, "node": node}
    if latched:
        h["latched"] = True
    return bytes(msgpack.packb(h))


@pytest.fixture
def dealer() -> Iterator[zmq.Socket[bytes]]:
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.DEALER)
    sock.linger = 0
    yield sock
    sock.close(0)


def ask(sock: zmq.Socket[bytes], *frames: bytes) -> list[bytes]:
    sock.send_multipart(list(frames))
    assert sock.poll(5000), f"no reply to {frames[:2]!r}"
    return sock.recv_multipart()


@pytest.mark.system
def test_latch_cache_refuses_malformed_unlatched_and_oversized_sets(dealer: zmq.Socket[bytes]) -> None:
    with Bus(bus_spec("ipc"), latched_topics=["graph/cal"], latch_max_entries=2, latch_max_bytes=4096) as bus:
        assert bus.address is not None
        dealer.connect(bus.address.latch)
        text = msgpack.packb({"text": "ok"})
        err = ask(dealer, b"SET", b"a/topic")
        assert err[0] == b"ERR" and b"SET needs topic, header and payload" in err[2]
        err = ask(dealer, b"SET", b"a/topic", b"\xc1garbage", text)
        assert err[0] == b"ERR" and b"bad envelope header" in err[2]
        err = ask(dealer, b"SET", b"not/latched", header(1), text)
        assert err[0] == b"ERR" and b"not latched" in err[2]
        err = ask(dealer, b"SET", b"a/topic", header(1, latched=True), msgpack.packb({"text": 5}))
        assert err[0] == b"ERR" and b"Expected `str`" in err[2]  # a declared type is validated
        err = ask(dealer, b"SET", b"a/topic", header(1, type_="Unknown", latched=True), b"\x93\x01\x02\x03")
        assert err[0] == b"ERR" and b"not a msgpack map" in err[2]
        err = ask(dealer, b"FOO")
        assert err[0] == b"ERR" and b"unknown request" in err[2]
        # well-formed values are stored, up to the bounds
        dealer.send_multipart([b"SET", b"graph/cal", header(1), text])  # graph-latched: no flag needed
        dealer.send_multipart([b"SET", b"a/topic", header(1, latched=True), text])
        wait_until(lambda: bus.cached_topics() == ["a/topic", "graph/cal"], 5)
        err = ask(dealer, b"SET", b"b/topic", header(1, latched=True), text)
        assert err[0] == b"ERR" and b"2 topics" in err[2]
        big = msgpack.packb({"text": "x" * 5000})
        err = ask(dealer, b"SET", b"a/topic", header(2, latched=True), big)
        assert err[0] == b"ERR" and b"bytes" in err[2]
        assert bus.latch_refused == 7
        assert ask(dealer, b"GET", b"a/")[3] == text  # the refused value did not replace the stored one


@pytest.mark.system
def test_graph_latched_topic_is_cached_with_no_subscriber_ever() -> None:
    with Bus(bus_spec("ipc"), latched_topics=["graph/cal"]) as bus:
        assert bus.address is not None
        with palpa.Node(name="plain", bus=bus.address, heartbeat_s=0) as node:
            pub = node.publisher("graph/cal", Text)
            # the bus itself subscribes to its latched topics, so the publisher hears a subscriber
            assert pub.wait_for_subscribers(5.0)
            pub.publish(Text(text="calibration"))
            wait_until(lambda: bus.cached_topics() == ["graph/cal"], 5)
        with palpa.Node(name="late", bus=bus.address, heartbeat_s=0) as late:
            assert late.subscribe("graph/cal", Text).next(5.0) == Text(text="calibration")


@pytest.mark.system
def test_a_message_over_the_bus_limit_disconnects_its_sender_and_reaches_nobody(ipc_bus: BusAddress) -> None:
    with Bus(bus_spec("ipc"), max_msg_bytes=4096) as bus:
        assert bus.address is not None
        with palpa.Node(name="good", bus=bus.address, heartbeat_s=0) as good, \
                palpa.Node(name="bad", bus=bus.address, heartbeat_s=0) as bad, \
                palpa.Node(name="listener", bus=bus.address, heartbeat_s=0) as listener:
            sub = listener.subscribe("chatter", Text)
            big_pub = bad.publisher("chatter", Text, batch=1)
            pub = good.publisher("chatter", Text, batch=1)
            assert pub.wait_for_subscribers(5.0) and big_pub.wait_for_subscribers(5.0)
            big_pub.publish(Text(text="x" * 10_000))
            pub.publish(Text(text="small"))
            assert sub.next(5.0) == Text(text="small")
            listener.spin_once(0.2)
            assert not sub.queue


@pytest.mark.system
def test_a_node_refuses_and_counts_messages_over_its_limit(ipc_bus: BusAddress) -> None:
    options = TransportOptions(max_msg_bytes=2048)
    with palpa.Node(name="small", transport=ZmqTransport(ipc_bus, options), heartbeat_s=0) as node, \
            palpa.Node(name="talker", bus=ipc_bus, heartbeat_s=0) as talker:
        sub = node.subscribe("chatter", Text)
        pub = talker.publisher("chatter", Text, batch=1)
        assert pub.wait_for_subscribers(5.0)
        # every frame under the limit, the message over it: refused by the node and counted
        talker.publish_raw("chatter", msgspec.msgpack.decode(header(1), type=palpa.net.wire.Header),
                           msgpack.packb({"text": "a"}), [b"b" * 1500, b"c" * 1500])
        pub.publish(Text(text="fits"))
        assert sub.next(5.0) == Text(text="fits")
        stats = node.counters()["chatter"]
        assert stats.decode_errors == 1 and "refused (max_msg_bytes 2048)" in stats.last_error
    assert TransportOptions.from_env({"PALPA_TRANSPORT": '{"max_msg_bytes": 5000}'}).max_msg_bytes == 5000


def test_log_lines_on_the_bus_are_truncated() -> None:
    with NodeHarness(palpa.Node, name="chatty") as h:
        h.node.log.warning("payload %s", "z" * 100_000)
        h.spin()
        rec = h.published("_palpa/log", LogRecord)[-1]
        assert len(rec.text) < LOG_TEXT_MAX + 40 and rec.text.endswith("more chars)")


def test_recordings_flag_malformed_payloads_and_bag_info_escapes_names(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    h.publish_raw([b"chatter", header(1), msgpack.packb({"text": "fine"})])
    h.publish_raw([b"chatter", header(2), b"\xc1not msgpack"])
    h.publish_raw([b"chatter", header(3), msgpack.packb([1, 2])])
    h.publish_raw([b"evil\x1b[2Jtopic", header(1, node="n\x07"), msgpack.packb({"text": "x"})])
    h.close()
    assert "chatter: 2 decode errors" in h.node.report()
    assert json.loads(check_official(out).metadata[MD_DROPS]["chatter"])["decode_errors"] == 2
    assert main(["bag", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "\x1b" not in text and "\x07" not in text
    assert "evil\\x1b[2Jtopic" in text and "2 malformed" in text
