"""What docs/wire.md promises about the bus's sockets, checked with plain pyzmq clients: a latch ``GET``'s watch
ends with ``UNWATCH``; an XPUB on the ``pub`` endpoint hears each subscribed prefix once per connection (so a client
must remember them), ``\\x00`` only when the last subscriber leaves, and every current one again on a new
connection."""

from __future__ import annotations

from collections.abc import Iterator

import msgpack
import pytest
import zmq

from palpa.net.address import BusAddress
from palpa.net.wire import Header, encode_header
from tests.procs import replies_until_pong, wait_until

pytestmark = pytest.mark.system


@pytest.fixture
def sockets() -> Iterator[list[zmq.Socket[bytes]]]:
    made: list[zmq.Socket[bytes]] = []
    yield made
    for sock in made:
        sock.close(0)


def _socket(made: list[zmq.Socket[bytes]], kind: int, endpoint: str) -> zmq.Socket[bytes]:
    sock = zmq.Context.instance().socket(kind)
    made.append(sock)
    sock.connect(endpoint)
    return sock


def test_unwatch_ends_the_push_a_get_started(ipc_bus: BusAddress, sockets: list[zmq.Socket[bytes]]) -> None:
    setter = _socket(sockets, zmq.DEALER, ipc_bus.latch)
    watcher = _socket(sockets, zmq.DEALER, ipc_bus.latch)
    seq = 0

    def set_value() -> list[bytes]:
        """SET a new value, and what the watcher was pushed by then (the setter's PONG: the SET was handled;
        the watcher's PONG: after anything pushed to it)."""
        nonlocal seq
        seq += 1
        header = encode_header(Header(type="Text", seq=seq, stamp=1, node="setter", latched=True))
        setter.send_multipart([b"SET", b"w/topic", header, msgpack.packb({"text": str(seq)})])
        assert replies_until_pong(setter, b"set") == []
        return [msgpack.unpackb(f[3])["text"] for f in replies_until_pong(watcher, b"watch") if f[0] == b"VAL"]

    set_value()
    watcher.send_multipart([b"GET", b"w/"])
    assert set_value() == ["1", "2"]  # the cached value, then the push
    watcher.send_multipart([b"UNWATCH", b"w/"])
    assert set_value() == []
    watcher.send_multipart([b"UNWATCH", b"never/watched"])  # not an error: no reply at all
    assert replies_until_pong(watcher, b"quiet") == []
    watcher.send_multipart([b"GET", b"w/"])  # a new GET watches again
    assert set_value() == ["3", "4"]


def test_an_xpub_hears_each_subscription_once_per_connection(ipc_bus: BusAddress,
                                                             sockets: list[zmq.Socket[bytes]]) -> None:
    xpub = _socket(sockets, zmq.XPUB, ipc_bus.pub)
    first = _socket(sockets, zmq.SUB, ipc_bus.sub)
    second = _socket(sockets, zmq.SUB, ipc_bus.sub)

    def heard() -> bytes:
        assert xpub.poll(5000), "no subscription message within 5 s"
        return xpub.recv()

    assert heard() == b"\x01_palpa/attach"  # the proxy's own, on every connection (docs/wire.md)
    first.subscribe(b"js/x")
    assert heard() == b"\x01js/x"
    # the second subscriber's js/x passes the proxy before its marker (one connection, in order): not repeated
    second.subscribe(b"js/x")
    second.subscribe(b"js/mark1")
    assert heard() == b"\x01js/mark1"
    first.unsubscribe(b"js/x")  # someone still listens: nothing
    first.subscribe(b"js/mark2")
    assert heard() == b"\x01js/mark2"
    second.unsubscribe(b"js/x")
    assert heard() == b"\x00js/x"
    # a new connection hears every current subscription once, at once
    late = _socket(sockets, zmq.XPUB, ipc_bus.pub)
    got: set[bytes] = set()

    def take() -> None:
        if late.poll(50):
            got.add(late.recv())

    wait_until(lambda: {b"\x01js/mark1", b"\x01js/mark2"} <= got, 5, "the current subscriptions", step=take)
    assert b"\x01js/x" not in got
