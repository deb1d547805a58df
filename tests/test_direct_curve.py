"""Direct topics on a CURVE bus (issue 22): the publisher's own socket is a CURVE server with a key announced through
the bus's authenticated directory, and it lets in exactly the clients the bus lets in, including keys the bus
learns on reload. Across hosts: tests/test_multihost.py."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq
import zmq.auth

import palpa
from messages import Text
from palpa.net.address import BusAddress
from palpa.net.bus import Bus, CurveServer
from palpa.net.direct import CLIENT_KEYS_TOPIC
from palpa.net.keys import create_key_pair
from palpa.net.latch import LatchCache
from palpa.net.transport import ZmqTransport
from tests.procs import wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

TCP = BusAddress("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*")


@pytest.fixture
def curve_bus(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Bus, Path]]:
    """A CURVE bus on loopback tcp that authorises ``good`` (not ``other``); this process's nodes are ``good``."""
    keys, clients = tmp_path / "keys", tmp_path / "clients"
    clients.mkdir()
    for who in ("server", "good", "other"):
        create_key_pair(keys, who)
    (clients / "good.key").write_bytes((keys / "good.key").read_bytes())
    monkeypatch.setenv("PALPA_BUS_SERVER_KEY", str(keys / "server.key"))
    monkeypatch.setenv("PALPA_CURVE_SECRET", str(keys / "good.key_secret"))
    with Bus(TCP, curve=CurveServer(keys / "server.key_secret", clients)) as bus:
        yield bus, keys


def _raw_sub(keys: Path, who: str, server_key: bytes | None, endpoint: str) -> zmq.Socket[bytes]:
    """A plain pyzmq SUB to every topic at ``endpoint``, with ``who``'s keys (None: no CURVE at all)."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.linger = 0
    if server_key is not None:
        sock.curve_publickey, sock.curve_secretkey = zmq.auth.load_certificate(str(keys / f"{who}.key_secret"))
        sock.curve_serverkey = server_key
    sock.subscribe(b"")
    sock.connect(endpoint)
    return sock


def _transport(node: palpa.Node) -> ZmqTransport:
    assert isinstance(node.transport, ZmqTransport)
    return node.transport


def test_a_direct_topic_on_a_curve_bus_is_encrypted_and_open_only_to_the_bus_s_clients(
        curve_bus: tuple[Bus, Path], caplog: pytest.LogCaptureFixture) -> None:
    bus, keys = curve_bus
    assert bus.address is not None
    with palpa.Node(name="sub", bus=bus.address, heartbeat_s=0) as sub_node, \
            palpa.Node(name="pub", bus=bus.address, heartbeat_s=0) as pub_node:

        def spin() -> None:
            sub_node.spin_once(0.005)
            pub_node.spin_once(0.005)

        got: list[str] = []
        sub_node.subscribe("fast", Text, lambda m: got.append(m.text))
        # the subscription reaches the publisher through the bus first; that is not a listener of a direct topic
        wait_until(lambda: _transport(pub_node).has_subscribers(b"fast"), 10, "the subscription via the bus",
                   step=spin)
        fast = pub_node.publisher("fast", Text, direct=True)
        assert not fast.has_subscribers
        direct = _transport(pub_node)._direct
        assert fast.direct and direct is not None and direct.endpoint.startswith("tcp://127.0.0.1:")
        wait_until(lambda: fast.has_subscribers, 10, "the subscriber on the direct socket", step=spin)
        for i in range(300):
            fast.publish(Text(text=str(i)))
        wait_until(lambda: len(got) >= 300, 10, "every message", step=spin)
        assert got == [str(i) for i in range(300)]
        assert (sub_node.counters()["fast"].gaps, sub_node.counters()["fast"].duplicates) == (0, 0)
        assert "fast" not in bus.cached_topics() and "_palpa/curve/clients" not in bus.cached_topics()

        # a client the bus does not know, and one without CURVE, hear nothing from the direct socket
        server_key = direct.server_key
        assert server_key is not None
        with caplog.at_level(logging.WARNING, logger="palpa.net.transport"):
            strangers = [_raw_sub(keys, "other", server_key, direct.endpoint),
                         _raw_sub(keys, "other", None, direct.endpoint)]
            wait_until(lambda: "refused a subscriber with key" in caplog.text, 10, "the refusal to be logged",
                       step=spin)
        for _ in range(20):
            fast.publish(Text(text="private"))
            spin()
        assert not any(s.poll(200) for s in strangers)

        # the bus lets `other` in on reload: so does the direct socket, once the bus has pushed its new keys
        (bus.clients.directory / "other.key").write_bytes((keys / "other.key").read_bytes())  # type: ignore[union-attr]
        bus.clients.reload()  # type: ignore[union-attr]
        other_public = (keys / "other.key").read_text().split('public-key = "')[1].split('"')[0].encode()
        wait_until(lambda: direct.accepts(other_public), 10, "the new key to reach the publisher", step=spin)
        friend = _raw_sub(keys, "other", server_key, direct.endpoint)
        strangers.append(friend)

        def friend_hears() -> bool:
            fast.publish(Text(text="welcome"))
            spin()
            return bool(friend.poll(20))

        wait_until(friend_hears, 10, "the newly authorised client to hear the direct topic")
        for s in strangers:
            s.close(0)


def test_only_the_bus_writes_the_client_keys() -> None:
    why = LatchCache(frozenset()).check(CLIENT_KEYS_TOPIC, [b"", b"forged-key"])
    assert why is not None and "bus only" in why
