"""Services over a real ZeroMQ bus: a server in another thread, a node calling its own service, and a client
written from docs/wire.md alone with plain pyzmq + msgpack."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import msgpack
import pytest
import zmq

import palpa
from palpa.net.address import BusAddress
from palpa.node.service import RequestRefused
from tests.procs import wait_until
from tests.test_service import Adder, AddReply, AddRequest

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


@pytest.fixture
def adder(ipc_bus: BusAddress) -> Iterator[Adder]:
    """An Adder node spinning in its own thread on the bus."""
    node = Adder(name="adder", bus=ipc_bus, heartbeat_s=0.2)
    thread = threading.Thread(target=node.spin, daemon=True)
    thread.start()
    yield node
    node.request_shutdown()
    thread.join(5)
    node.close(0)


def test_call_over_zmq_and_from_inside_a_callback(ipc_bus: BusAddress, adder: Adder) -> None:
    results: list[float] = []

    class Caller(palpa.Node):
        def setup(self) -> None:
            self.add = self.client("math/add", AddRequest, AddReply)
            self.timer(0.01, self.tick)

        def tick(self) -> None:
            results.append(self.add.call(AddRequest(a=len(results), b=0.5), timeout_s=5.0).total)

    with Caller(name="caller", bus=ipc_bus, heartbeat_s=0) as caller:
        assert caller.add.wait_for_service(5.0)
        with pytest.raises(RequestRefused):
            caller.add.call(AddRequest(a=-3, b=0))
        wait_until(lambda: len(results) >= 3, 10, "three calls from the timer", step=lambda: caller.spin_once(0.05))
    assert results[:3] == [0.5, 1.5, 2.5]


def test_node_calls_its_own_service_over_zmq(ipc_bus: BusAddress) -> None:
    with palpa.Node(name="selfish", bus=ipc_bus, heartbeat_s=0) as node:
        node.service("me/add", AddRequest, AddReply, lambda r: AddReply(total=r.a + r.b))
        me = node.client("me/add", AddRequest, AddReply)
        assert me.wait_for_service(5.0)
        got: list[float] = []
        node.timer(0.001, lambda: got.append(me.call(AddRequest(a=2, b=2), timeout_s=5.0).total), oneshot=True)
        wait_until(lambda: node.spin_once(0.01) or got, 10, "the own-service call from a timer")
        assert got == [4.0]


def test_foreign_client_plain_pyzmq(ipc_bus: BusAddress, adder: Adder) -> None:
    """docs/wire.md, *Services*: find the server in the latch cache, subscribe to the reply topic, wait until the
    subscription is live, send the request, match the reply by seq."""
    ctx = zmq.Context()
    pub = ctx.socket(zmq.XPUB)
    sub = ctx.socket(zmq.SUB)
    latch = ctx.socket(zmq.DEALER)
    try:
        pub.connect(ipc_bus.pub)
        sub.connect(ipc_bus.sub)
        latch.connect(ipc_bus.latch)
        latch.send_multipart([b"GET", b"_palpa/srv/math/add"])
        assert latch.poll(5000), "no ServiceInfo in the latch cache"
        verb, topic, _header, payload = latch.recv_multipart()[:4]
        info = msgpack.unpackb(payload)
        assert (verb, topic) == (b"VAL", b"_palpa/srv/math/add") and info["alive"] is not False
        assert info["request_type"] == "AddRequest" and info["response_type"] == "AddReply"
        me = "foreign.42"
        reply_topic = f"math/add/reply/{me}".encode()
        sub.setsockopt(zmq.SUBSCRIBE, reply_topic)
        heard: set[bytes] = set()
        def live() -> bool:
            return reply_topic in heard and any(b"math/add/request".startswith(h) for h in heard)

        def hear() -> None:
            if pub.poll(100):
                heard.add(pub.recv()[1:])   # \x01topic: a subscription that reached the bus

        wait_until(live, 5, "the reply and request subscriptions at the bus", step=hear)
        header = msgpack.packb({"type": "AddRequest", "seq": 1, "stamp": time.time_ns(), "node": me})
        pub.send_multipart([b"math/add/request", header, msgpack.packb({"a": 40, "b": 2})])
        assert sub.poll(5000), "no reply"
        topic, header, payload = sub.recv_multipart()[:3]
        h = msgpack.unpackb(header)
        assert topic == reply_topic and h["seq"] == 1 and h["type"] == "AddReply"
        assert msgpack.unpackb(payload) == {"total": 42.0}
    finally:
        for s in (pub, sub, latch):
            s.close(0)
        ctx.term()
