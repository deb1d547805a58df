"""A node counts as ready (heartbeats, its first lockstep ack, a player's ``wait_for``) only once its subscriptions
are live end to end: nothing published to it afterwards is dropped by ZeroMQ for lack of a route (palpa.presence)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
import zmq

import palpa
from messages import Text
from palpa.address import BusAddress
from palpa.direct import JOIN_PROBE_PREFIX
from palpa.runtime_msgs import HEARTBEAT_TOPIC
from palpa.transport import ZmqTransport
from tests.procs import short_ipc_base, wait_until


class SubscriptionGate:
    """A relay in front of the bus's ``sub`` endpoint (XPUB towards the node, XSUB towards the proxy) that passes
    messages at once but holds the node's subscriptions back until :meth:`open`: a subscription slowed down on its
    way to the proxy, as a loaded machine slows it."""

    def __init__(self, bus: BusAddress) -> None:
        self._ctx = zmq.Context()
        self._front = self._ctx.socket(zmq.XPUB)
        self._front.linger = 0
        self._front.bind(f"ipc://{short_ipc_base()}.gate")
        self._back = self._ctx.socket(zmq.XSUB)
        self._back.linger = 0
        self._back.connect(bus.sub)
        self.address = BusAddress(bus.pub, self._front.getsockopt_string(zmq.LAST_ENDPOINT), bus.latch)
        self.held: list[bytes] = []
        self.opened_ns = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._relay, daemon=True)

    def holds(self, prefix: bytes) -> bool:
        with self._lock:
            return any(s[1:].startswith(prefix) for s in self.held)

    def open(self) -> None:
        with self._lock:
            self.opened_ns = time.time_ns()

    def _relay(self) -> None:
        poller = zmq.Poller()
        poller.register(self._front, zmq.POLLIN)
        poller.register(self._back, zmq.POLLIN)
        while not self._stop.is_set():
            events = dict(poller.poll(10))
            if self._back in events:
                self._front.send_multipart(self._back.recv_multipart())
            if self._front in events:
                with self._lock:
                    self.held.append(self._front.recv())
            with self._lock:
                if self.opened_ns:
                    for sub in self.held:
                        self._back.send(sub)
                    self.held.clear()

    def __enter__(self) -> SubscriptionGate:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        self._front.close(0)
        self._back.close(0)
        self._ctx.term()


class _Listener(palpa.Node):
    def setup(self) -> None:
        self.heard = self.subscribe("chatter", Text)


@pytest.fixture
def gate(ipc_bus: BusAddress) -> Iterator[SubscriptionGate]:
    with SubscriptionGate(ipc_bus) as g:
        yield g


def test_a_node_is_ready_only_once_the_bus_has_its_subscriptions(ipc_bus: BusAddress, gate: SubscriptionGate) -> None:
    """While its subscriptions are held on their way to the proxy the node is not ready (its constructor waits, it
    sends no heartbeat); once a publisher has heard its readiness probe, the first message published reaches it."""
    with palpa.Node(name="talker", bus=ipc_bus, heartbeat_s=0) as talker:
        pub = talker.publisher("chatter", Text)
        beats: list[int] = []
        talker.subscribe_raw(HEARTBEAT_TOPIC, lambda raw: beats.append(raw.header.stamp)
                             if raw.header.node == "listener" else None)
        built: list[palpa.Node] = []
        thread = threading.Thread(target=lambda: built.append(
            _Listener(name="listener", bus=gate.address, heartbeat_s=0.01)))
        thread.start()
        try:
            wait_until(lambda: built or gate.holds(JOIN_PROBE_PREFIX), 20, "the listener ready, or its probe held",
                       step=lambda: talker.spin_once(0.01))
            assert not built, "the listener said it was ready while the bus did not have its subscriptions"
            gate.open()
        finally:
            gate.open()  # never leave the constructor waiting
            thread.join(20)
        listener = built[0]
        assert isinstance(listener, _Listener)
        transport = talker.transport
        assert isinstance(transport, ZmqTransport)
        try:
            wait_until(lambda: transport.heard_join("listener"), 10, "the talker to hear the listener's probe",
                       step=lambda: talker.spin_once(0.01))
            pub.publish(Text(text="first"))
            wait_until(lambda: listener.heard.queue, 10, "the first message", step=lambda: listener.spin_once(0.01))
            assert listener.heard.queue[0].text == "first"
            def spin_both() -> None:
                listener.spin_once(0.01)
                talker.spin_once(0.01)

            wait_until(lambda: beats, 10, "a heartbeat of the ready listener", step=spin_both)
            assert min(beats) >= gate.opened_ns  # no heartbeat while its subscriptions were held
        finally:
            listener.close(0)
