"""Direct topics (palpa.net.direct): published straight to subscribers, found through the bus's directory, never
through the proxy; and the publisher-side subscriber check every topic has."""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zmq

import palpa
from messages import Text
from palpa.launch import load_launch
from palpa.net.address import BusAddress
from palpa.net.direct import (
    SubscriberSet,
    bind_candidates,
    directory_entry,
    directory_key,
    directory_value,
)
from palpa.net.transport import TransportOptions, ZmqTransport
from palpa.node.endpoints import RawMessage
from palpa.testing import MemoryBus
from tests.procs import ProcessGroup, palpa_cmd, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


def _texts(n: int, start: int = 0) -> list[str]:
    return [str(i) for i in range(start, start + n)]


@contextlib.contextmanager
def proxy_spy(address: BusAddress, *topics: bytes) -> Iterator[zmq.Socket[bytes]]:
    """A plain SUB on the proxy: sees whatever passes through the bus for ``topics``."""
    ctx = zmq.Context.instance()
    spy = ctx.socket(zmq.SUB)
    for topic in topics:
        spy.subscribe(topic)
    spy.connect(address.sub)
    try:
        yield spy
    finally:
        spy.close(0)


def _direct(node: palpa.Node) -> ZmqTransport:
    transport = node.transport
    assert isinstance(transport, ZmqTransport)
    return transport


def spinning(*nodes: palpa.Node) -> Callable[[], None]:
    """A wait_until step that gives each node a short spin."""
    def step() -> None:
        for node in nodes:
            node.spin_once(0.005)
    return step


def _endpoint(node: palpa.Node) -> str:
    direct = _direct(node)._direct
    assert direct is not None, "no direct socket"
    return direct.endpoint


def test_a_direct_topic_skips_the_proxy_and_arrives_complete_in_order(bus: BusAddress) -> None:
    """Over ipc and over loopback tcp: every message, in order, no gap; the proxy carries none of them while the
    same node's ordinary topic still goes through it."""
    with palpa.Node(name="sub", bus=bus, heartbeat_s=0) as sub_node, \
            palpa.Node(name="pub", bus=bus, heartbeat_s=0) as pub_node, \
            proxy_spy(bus, b"fast", b"slow") as spy:
        got: list[str] = []
        slow: list[str] = []
        sub_node.subscribe("fast", Text, lambda m: got.append(m.text))
        sub_node.subscribe("slow", Text, lambda m: slow.append(m.text))
        fast = pub_node.publisher("fast", Text, direct=True)
        plain = pub_node.publisher("slow", Text)
        endpoint = _endpoint(pub_node)
        assert endpoint.startswith("ipc://" if bus.pub.startswith("ipc://") else "tcp://127.0.0.1:")
        wait_until(lambda: fast.has_subscribers and plain.has_subscribers, 10, "both subscriptions",
                   step=spinning(sub_node, pub_node))

        def spy_hears_the_bus() -> bool:  # both of the spy's subscriptions are then in place (one connection)
            plain.publish(Text(text="probe"))
            return bool(spy.poll(50))

        wait_until(spy_hears_the_bus, 10, "the spy's subscriptions")
        for text in _texts(500):
            fast.publish(Text(text=text))
        plain.publish(Text(text="via the bus"))
        wait_until(lambda: len(got) >= 500 and "via the bus" in slow, 10, "every message",
                   step=lambda: sub_node.spin_once(0.01))
        assert got == _texts(500)
        stats = sub_node.counters()["fast"]
        assert (stats.received, stats.gaps, stats.duplicates) == (500, 0, 0)
        # what the proxy carried, up to the message sent after the direct ones: ordinary topic only
        seen: list[bytes] = []
        while b"via the bus" not in (seen[-1] if seen else b""):
            assert spy.poll(5000), "the proxy never carried the ordinary topic's message"
            topic, _header, payload = spy.recv_multipart()
            seen.append(topic + b" " + payload)
        assert all(item.startswith(b"slow ") for item in seen)


def test_subscribers_find_publishers_that_start_before_or_after_them(ipc_bus: BusAddress) -> None:
    """An early subscriber is told of a later publisher; a late subscriber finds it in the directory; a raw
    subscription to every topic (what the recorder uses) finds it too."""
    with palpa.Node(name="early", bus=ipc_bus, heartbeat_s=0) as early:
        got_early: list[str] = []
        early.subscribe("fast", Text, lambda m: got_early.append(m.text))
        early.spin_once(0.01)
        with palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0) as pub_node, \
                palpa.Node(name="late", bus=ipc_bus, heartbeat_s=0) as late:
            fast = pub_node.publisher("fast", Text, direct=True)
            got_late: list[str] = []
            raw: list[RawMessage] = []
            late.subscribe("fast", Text, lambda m: got_late.append(m.text))
            late.subscribe_raw("", raw.append)
            listeners = [early, late]

            def both_hear_it() -> bool:
                # XPUB reports a topic's first subscriber only, so readiness is seen by a probe reaching both
                fast.publish(Text(text="probe"))
                spinning(*listeners)()
                return "probe" in got_early and "probe" in got_late

            wait_until(both_hear_it, 10, "both subscribers to hear the publisher", step=spinning(pub_node))
            assert all(_direct(n)._peers == {_endpoint(pub_node)} for n in listeners)
            for text in _texts(50):
                fast.publish(Text(text=text))
            wait_until(lambda: got_early[-1:] == got_late[-1:] == ["49"], 10, "every message",
                       step=spinning(*listeners))
            assert [t for t in got_early if t != "probe"] == [t for t in got_late if t != "probe"] == _texts(50)
            assert len([r for r in raw if r.topic == "fast"]) == len(got_late)
            assert early.counters()["fast"].gaps == late.counters()["fast"].gaps == 0


def test_a_closed_publisher_withdraws_and_removes_its_socket_file(ipc_bus: BusAddress) -> None:
    with palpa.Node(name="sub", bus=ipc_bus, heartbeat_s=0) as sub_node:
        sub_node.subscribe("fast", Text)
        pub_node = palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0)
        pub_node.publisher("fast", Text, direct=True)
        endpoint = _endpoint(pub_node)
        wait_until(lambda: _direct(sub_node)._peers == {endpoint}, 10, "the connection",
                   step=lambda: sub_node.spin_once(0.01))
        assert Path(endpoint[len("ipc://"):]).exists()
        pub_node.close(1.0)
        assert not Path(endpoint[len("ipc://"):]).exists()
        # a subscriber that joins now connects to a live publisher of the topic, not to the withdrawn one (the
        # cache answers with both entries at once, so once the live one is connected the other was read too)
        with palpa.Node(name="alive", bus=ipc_bus, heartbeat_s=0) as alive, \
                palpa.Node(name="later", bus=ipc_bus, heartbeat_s=0) as later:
            alive.publisher("fast", Text, direct=True)
            later.subscribe("fast", Text)
            wait_until(lambda: _endpoint(alive) in _direct(later)._peers, 10, "the live publisher",
                       step=lambda: later.spin_once(0.01))
            later.spin_once(0)
            assert _direct(later)._peers == {_endpoint(alive)}


def test_what_a_closing_publisher_still_had_queued_is_delivered(ipc_bus: BusAddress) -> None:
    """The publisher closes (and withdraws) while most of a burst is still queued on its side: the subscriber,
    reading only afterwards, still gets all of it (dropping the connection on withdrawal lost 86 000 of 200 000
    messages in the benchmark)."""
    n = 30_000
    with palpa.Node(name="sub", bus=ipc_bus, heartbeat_s=0, transport_options=TransportOptions(rcvhwm=0)) as sub_node:
        got: list[str] = []
        sub_node.subscribe("fast", Text, lambda m: got.append(m.text))
        pub_node = palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0, transport_options=TransportOptions(sndhwm=0))
        fast = pub_node.publisher("fast", Text, direct=True)
        wait_until(lambda: fast.has_subscribers, 10, "the subscription",
                   step=spinning(sub_node, pub_node))
        for text in _texts(n):
            fast.publish(Text(text=text))
        pub_node.close(10.0)
        wait_until(lambda: len(got) >= n, 30, f"{n} messages", step=lambda: sub_node.spin_once(0.01))
        assert got == _texts(n) and sub_node.counters()["fast"].gaps == 0


def test_a_latched_direct_topic_still_reaches_a_late_joiner(ipc_bus: BusAddress) -> None:
    with palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0) as pub_node:
        plan = pub_node.publisher("scan/plan", Text, latched=True, direct=True)
        plan.publish(Text(text="the plan"))
        with palpa.Node(name="late", bus=ipc_bus, heartbeat_s=0) as late:
            sub = late.subscribe("scan/plan", Text)
            msg = sub.next(timeout_s=10)
            assert msg is not None and msg.text == "the plan"


def test_options_launch_and_command_line_make_a_topic_direct(tmp_path: Path, ipc_bus: BusAddress,
                                                             procs: ProcessGroup, env_for) -> None:  # type: ignore[no-untyped-def]
    assert TransportOptions.from_env({"PALPA_TRANSPORT": '{"direct": ["a/b", "c"]}'}).direct == ("a/b", "c")
    assert TransportOptions.from_env({"PALPA_TRANSPORT": '{"direct": ["a"]}'}, direct=("x",)).direct == ("x",)
    with pytest.raises(palpa.BusError, match="expected a list of topic names"):
        TransportOptions(direct="chatter")  # type: ignore[arg-type]

    f = tmp_path / "g.yaml"
    f.write_text("nodes:\n  - {name: talker, node: nodes.demo:Talker, transport: {direct: [chatter, other]}}\n")
    (talker,) = load_launch(f).nodes
    env = talker.child_env({}, bus=None, run_dir=tmp_path, python_path=[])
    assert TransportOptions.from_env(env).direct == ("chatter", "other")
    assert talker.as_dict()["transport"] == {"direct": ["chatter", "other"]}

    # a node process given --direct publishes that topic past the proxy
    with palpa.Node(name="listen", bus=ipc_bus, heartbeat_s=0) as node, \
            proxy_spy(ipc_bus, b"chatter", b"_palpa/heartbeat") as spy:
        got: list[str] = []
        node.subscribe("chatter", Text, lambda m: got.append(m.text))
        procs.start(palpa_cmd("run", "nodes.demo:Talker", "--direct", "chatter", "-p", "rate_hz=200"),
                    env=env_for(ipc_bus))
        wait_until(lambda: len(got) >= 20, 20, "20 messages from the talker", step=lambda: node.spin_once(0.05))
        assert len(_direct(node)._peers) == 1
        # the talker's heartbeats (1 Hz) go through the proxy: between two of them, no chatter does
        carried: list[bytes] = []
        while carried.count(b"_palpa/heartbeat") < 2:
            assert spy.poll(5000), "no heartbeat through the proxy"
            carried.append(spy.recv_multipart()[0])
        assert b"chatter" not in carried


def test_direct_falls_back_to_the_bus_where_it_cannot_bind(ipc_bus: BusAddress,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    """A remote tcp bus without CURVE: a plaintext socket beyond loopback would be open to the network, so the
    topic stays on the bus, with a warning."""
    assert bind_candidates(BusAddress.parse("tcp://10.1.2.3:7000")) == []
    assert bind_candidates(BusAddress.parse("tcp://127.0.0.1.nip.io:7000")) == []
    assert bind_candidates(BusAddress.parse("tcp://localhost:7000")) == ["tcp://127.0.0.1:*"]
    first, second = bind_candidates(BusAddress.parse("ipc:///tmp/pq"))
    assert first.startswith(f"ipc:///tmp/pq.d{os.getpid()}-") and second.startswith("ipc://")
    assert len(bind_candidates(BusAddress.parse("ipc:///tmp/" + "x" * 88))) == 1  # too long next to the bus
    with palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0) as node:
        transport = _direct(node)
        transport._address = BusAddress.parse("tcp://10.1.2.3:7000")  # as if the bus were on another host
        with caplog.at_level(logging.WARNING, logger="palpa.net.transport"):
            pub = node.publisher("fast", Text, direct=True)
        assert pub._send == transport.send
        assert "fast goes through the bus, not direct" in caplog.text and "10.1.2.3" in caplog.text
        assert "beyond loopback, direct topics need CURVE" in caplog.text


def test_directory_entries_and_subscriber_sets() -> None:
    key = directory_key(b"probe/h", "ipc:///tmp/x.d1-0")
    assert directory_entry(key, b"ipc:///tmp/x.d1-0") == ("ipc:///tmp/x.d1-0", True, None)
    assert directory_entry(key, b"") == ("ipc:///tmp/x.d1-0", False, None)
    value = directory_value("ipc:///tmp/x.d1-0", b"K" * 40)
    assert directory_entry(key, value) == ("ipc:///tmp/x.d1-0", True, b"K" * 40)
    assert directory_entry(b"probe/h", b"x") is None
    subs = SubscriberSet()
    subs.note(b"\x01probe/")
    assert subs.covers(b"probe/h") and not subs.covers(b"map")
    subs.note(b"\x00probe/")
    assert not subs.covers(b"probe/h")
    subs.note(b"\x01ma")  # the answers are kept per topic: a new subscription changes them
    assert subs.covers(b"map") and not subs.covers(b"probe/h")


def test_has_subscribers_on_the_bus_and_in_memory(ipc_bus: BusAddress) -> None:
    with palpa.Node(name="pub", bus=ipc_bus, heartbeat_s=0) as pub_node:
        pub = pub_node.publisher("lonely", Text)
        assert not pub.wait_for_subscribers(0.2)
        with palpa.Node(name="sub", bus=ipc_bus, heartbeat_s=0) as sub_node:
            sub_node.subscribe("lonely", Text)
            assert pub.wait_for_subscribers(10)
        wait_until(lambda: not pub.has_subscribers, 10, "the unsubscription", step=lambda: pub_node.spin_once(0.01))
    bus = MemoryBus()
    a = palpa.Node(name="a", transport=bus.transport(), heartbeat_s=0)
    b = palpa.Node(name="b", transport=bus.transport(), heartbeat_s=0)
    out = a.publisher("x", Text, direct=True)
    assert not out.has_subscribers
    b.subscribe("x", Text)
    assert out.has_subscribers


def test_topic_tools_follow_a_direct_topic(ipc_bus: BusAddress, procs: ProcessGroup, env_for) -> None:  # type: ignore[no-untyped-def]
    """`palpa topic echo/hz/list` and `node list` on a topic published past the proxy: they find it through the
    bus like any subscriber, and the listings say it is direct."""
    env = env_for(ipc_bus)
    procs.start(palpa_cmd("run", "nodes.demo:Talker", "-p", "rate_hz=200", "--direct", "chatter"), env=env)
    echo = procs.start(palpa_cmd("topic", "echo", "chatter", "-n", "2", "--timeout", "10"), env=env)
    assert echo.wait(15) == 0 and "text: hello" in echo.output()
    hz = procs.start(palpa_cmd("topic", "hz", "chatter", "--duration", "1.5"), env=env)
    assert hz.wait(15) == 0
    assert " gaps 0" in hz.output().strip().splitlines()[-1]
    nl = procs.start(palpa_cmd("node", "list", "-v"), env=env)
    assert nl.wait(15) == 0 and "pub chatter [Text] sent" in nl.output() and "(direct)" in nl.output()
    tl = procs.start(palpa_cmd("topic", "list"), env=env)
    assert tl.wait(15) == 0 and "chatter  [Text]  pub: talker (direct)" in tl.output()
