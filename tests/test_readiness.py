"""A node counts as ready (heartbeats, its first lockstep ack, a player's ``wait_for``) only once its subscriptions
are live end to end: nothing published to it afterwards is dropped by ZeroMQ for lack of a route (palpa.node.presence)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Self

import pytest
import zmq

import palpa
from messages import Text
from palpa.net.address import BusAddress
from palpa.net.direct import JOIN_PROBE_PREFIX
from palpa.net.transport import ZmqTransport
from palpa.runtime_msgs import HEARTBEAT_TOPIC
from tests.procs import short_ipc_base, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


class _Gate:
    """A relay thread between a front socket (bound on a short ipc path, :attr:`endpoint`) and a back socket
    connected to ``upstream``: what a subclass's :meth:`_pass` holds back stands for traffic slowed on its way."""

    def __init__(self, upstream: str, front: int, back: int, suffix: str) -> None:
        self._ctx = zmq.Context()
        self._front = self._ctx.socket(front)
        self._front.linger = 0
        self._front.bind(f"ipc://{short_ipc_base()}.{suffix}")
        self._back = self._ctx.socket(back)
        self._back.linger = 0
        self._back.connect(upstream)
        self.endpoint = self._front.getsockopt_string(zmq.LAST_ENDPOINT)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._relay, daemon=True)

    def _relay(self) -> None:
        poller = zmq.Poller()
        poller.register(self._front, zmq.POLLIN)
        poller.register(self._back, zmq.POLLIN)
        while not self._stop.is_set():
            self._pass(dict(poller.poll(10)))

    def _pass(self, events: dict[zmq.Socket[bytes], int]) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        self._front.close(0)
        self._back.close(0)
        self._ctx.term()


class SubscriptionGate(_Gate):
    """A relay in front of a socket that publishers send from (the bus's ``sub`` endpoint, or a node's direct
    socket): XPUB towards the subscriber, XSUB towards ``upstream``. It passes messages at once but holds the
    subscriber's subscriptions back until :meth:`open`: a subscription slowed down on its way, as a loaded machine
    slows it."""

    def __init__(self, upstream: str) -> None:
        super().__init__(upstream, zmq.XPUB, zmq.XSUB, "gate")
        self.held: list[bytes] = []
        self.opened_ns = 0

    def holds(self, prefix: bytes) -> bool:
        with self._lock:
            return any(s[1:].startswith(prefix) for s in self.held)

    def open(self) -> None:
        with self._lock:
            self.opened_ns = self.opened_ns or time.time_ns()

    def _pass(self, events: dict[zmq.Socket[bytes], int]) -> None:
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


class _Listener(palpa.Node):
    def setup(self) -> None:
        self.heard = self.subscribe("chatter", Text)


@pytest.fixture
def gate(ipc_bus: BusAddress) -> Iterator[SubscriptionGate]:
    with SubscriptionGate(ipc_bus.sub) as g:
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
            _Listener(name="listener", bus=BusAddress(ipc_bus.pub, gate.endpoint, ipc_bus.latch),
                                heartbeat_s=0.01)))
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


REACH_PROBES = b"_palpa/reach/"
"""Direct readiness probes on the wire (docs/wire.md, *Direct topics*)."""


def through_gate(monkeypatch: pytest.MonkeyPatch, publisher: str, gate: SubscriptionGate,
                 only: zmq.Socket[bytes] | None = None) -> None:
    """Make subscribers in this process (or the one reading on socket ``only``) connect to ``gate`` where the
    directory names ``publisher``: the directory still says ``publisher`` (so does the publisher's answer to a
    probe); only the connection goes round."""
    import palpa.net.transport

    follow = palpa.net.transport.follow_directory

    def via_gate(sub: zmq.Socket[bytes], peers: set[str], key: bytes, payload: bytes,
                 bus_key: bytes | None) -> str | None:
        if key.endswith(b"\0" + publisher.encode()) and payload and (only is None or sub is only):
            key = key[: -len(publisher)] + gate.endpoint.encode()
            payload = gate.endpoint.encode()
            return publisher if follow(sub, peers, key, payload, bus_key) else None  # the name, not the way round
        return follow(sub, peers, key, payload, bus_key)

    monkeypatch.setattr(palpa.net.transport, "follow_directory", via_gate)


def listener_behind(gate: _Gate, bus: BusAddress, talker: palpa.Node, held: Callable[[], bool],
                    what: str) -> _Listener:
    """Build the listener (in a thread: its constructor waits to be ready) while ``gate`` holds what it waits for;
    once ``held()`` says so, give it half a second more to say it is ready anyway (a listener that does not wait
    for it would), then open the gate. Returns the listener, ready."""
    built: list[_Listener] = []
    thread = threading.Thread(target=lambda: built.append(_Listener(name="listener", bus=bus, heartbeat_s=0)))
    thread.start()
    try:
        wait_until(lambda: built or held(), 20, f"the listener ready, or {what}", step=lambda: talker.spin_once(0.01))
        for _ in range(50):
            if built:
                break
            talker.spin_once(0.01)
        gate.open()
        wait_until(lambda: built, 20, "the listener ready", step=lambda: talker.spin_once(0.01))
    finally:
        gate.open()  # never leave the constructor waiting
        thread.join(20)
    return built[0]


def test_a_direct_subscriber_is_ready_only_once_the_publisher_has_its_subscriptions(
        ipc_bus: BusAddress, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """A topic published direct (no proxy): the listener's subscriptions are held on their way to the talker's
    direct socket. The talker publishes its first message as soon as the listener says it is ready (and the talker
    heard its readiness probe): that message must arrive. Before direct topics were covered the listener said it
    was ready at once, and the first message was lost to the slow joiner."""
    with palpa.Node(name="talker", bus=ipc_bus, heartbeat_s=0) as talker:
        pub = talker.publisher("chatter", Text, direct=True)
        transport = talker.transport
        assert isinstance(transport, ZmqTransport) and pub.direct
        endpoint = transport.direct_endpoint
        assert endpoint
        with SubscriptionGate(endpoint) as gate:
            through_gate(monkeypatch, endpoint, gate)
            # a listener that waits for its direct publisher shows it: the gate holds its direct probe
            listener = listener_behind(gate, ipc_bus, talker, lambda: gate.holds(REACH_PROBES), "its probe held")
            try:
                wait_until(lambda: transport.heard_join("listener"), 10, "the talker to hear the listener's probe",
                           step=lambda: talker.spin_once(0.01))
                pub.publish(Text(text="first"))
                gate.open()

                def again() -> None:  # the first may be lost: publish until something arrives, to say which
                    pub.publish(Text(text="again"))
                    listener.spin_once(0.01)

                wait_until(lambda: listener.heard.queue, 10, "a message at the listener", step=again)
                assert listener.heard.queue[0].text == "first", "the first message was lost"
                # ready because the talker confirmed, not because the wait ran out (the message came anyway)
                assert not [r for r in caplog.records if r.name == "palpa.node.listener" and r.levelno >= 30]
            finally:
                listener.close(0)


class ReplyGate(_Gate):
    """A relay in front of the bus's latch cache (ROUTER towards the node, DEALER towards the cache) that passes
    requests at once but holds the cache's replies, in order, until :meth:`open`: a directory answer slowed down."""

    def __init__(self, upstream: str) -> None:
        super().__init__(upstream, zmq.ROUTER, zmq.DEALER, "latch")
        self.held: list[list[bytes]] = []
        self._ident = b""
        self._open = threading.Event()

    def holds(self, verb: bytes) -> bool:
        with self._lock:
            return any(r[0] == verb for r in self.held)

    def open(self) -> None:
        self._open.set()

    def _pass(self, events: dict[zmq.Socket[bytes], int]) -> None:
        if self._front in events:
            self._ident, *request = self._front.recv_multipart()
            self._back.send_multipart(request)
        with self._lock:
            if self._back in events:
                self.held.append(self._back.recv_multipart())
            if self._open.is_set() and self._ident:
                for reply in self.held:
                    self._front.send_multipart([self._ident, *reply])
                self.held.clear()


def test_a_direct_subscriber_waits_for_the_directory_to_name_its_publishers(ipc_bus: BusAddress) -> None:
    """The directory's answer (the cache's, not the proxy's) is slow: a listener that said it was ready before it
    knew of the talker's direct socket would lose the first message, published as soon as it is ready."""
    with palpa.Node(name="talker", bus=ipc_bus, heartbeat_s=0) as talker, ReplyGate(ipc_bus.latch) as gate:
        pub = talker.publisher("chatter", Text, direct=True)
        assert pub.direct
        listener = listener_behind(gate, BusAddress(ipc_bus.pub, ipc_bus.sub, gate.endpoint), talker,
                                   lambda: gate.holds(b"PONG"), "its directory answer held")
        try:
            pub.publish(Text(text="first"))
            gate.open()

            def again() -> None:
                pub.publish(Text(text="again"))
                listener.spin_once(0.01)
                talker.spin_once(0)

            wait_until(lambda: listener.heard.queue, 10, "a message at the listener", step=again)
            assert listener.heard.queue[0].text == "first", "the first message was lost"
        finally:
            listener.close(0)
