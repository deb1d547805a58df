"""Services on the in-memory bus: replies, the typed errors, deferred answers, and calls from inside callbacks
(another node's service, a service that calls back, the node's own service) that complete instead of deadlocking."""

from __future__ import annotations

import msgspec
import pytest

import palpa
from palpa.net.wire import Header
from palpa.node.node import RawMessage
from palpa.node.service import (
    BadRequestError,
    HandlerError,
    NoServerError,
    RequestRefused,
    Responder,
    ServiceFault,
    ServiceTimeout,
    reply_topic,
    request_topic,
)
from palpa.node.service_client import Future, set_wait_pump
from palpa.testing import GraphHarness, MemoryBus


class AddRequest(palpa.Message, frozen=True, kw_only=True):
    a: float
    b: float


class AddReply(palpa.Message, frozen=True, kw_only=True):
    total: float


class Adder(palpa.Node):
    """Adds; refuses negative totals; raises on a == 13; answers a == 99 later (deferred)."""

    class Params(palpa.Params):
        offset: palpa.RunTime[float] = 0.0
        """Not used by the handler: a parameter to change at run time."""

    def setup(self) -> None:
        self.held: list[Responder[AddReply]] = []
        self.srv = self.service("math/add", AddRequest, AddReply, self.on_add)

    def on_add(self, req: AddRequest) -> AddReply | Responder[AddReply]:
        if req.a == 13:
            raise ZeroDivisionError("unlucky")
        if req.a == 99:
            responder = self.srv.defer()
            self.held.append(responder)
            return responder
        if req.a + req.b < 0:
            raise RequestRefused("negative totals are not served")
        return AddReply(total=req.a + req.b)


class Caller(palpa.Node):
    """Calls math/add from inside a timer (blocking) and from a subscription (future)."""

    def setup(self) -> None:
        self.add = self.client("math/add", AddRequest, AddReply, timeout_s=2.0)
        self.results: list[float] = []
        self.errors: list[Exception] = []
        self.timer(0.1, self.tick)

    def tick(self) -> None:
        try:
            self.results.append(self.add.call(AddRequest(a=1, b=len(self.results))).total)
        except palpa.PalpaError as exc:
            self.errors.append(exc)


def test_call_from_a_timer_completes_and_returns_the_reply() -> None:
    with GraphHarness([(Adder, None), (Caller, None)]) as g:
        caller = g.nodes[1]
        assert isinstance(caller, Caller)
        g.advance(0.35)
        assert caller.results == [1.0, 2.0, 3.0]
        assert caller.errors == []


def test_typed_errors_refused_handler_raised_bad_request_timeout() -> None:
    with GraphHarness([(Adder, None)]) as g:
        adder = g.nodes[0]
        assert isinstance(adder, Adder)
        c = g.add(palpa.Node, name="client")
        add = c.client("math/add", AddRequest, AddReply, timeout_s=0.2)
        assert add.wait_for_service(1.0)
        assert add.call(AddRequest(a=2, b=3)).total == 5.0
        with pytest.raises(RequestRefused, match="negative totals"):
            add.call(AddRequest(a=-5, b=1))
        with pytest.raises(HandlerError, match="ZeroDivisionError: unlucky"):
            add.call(AddRequest(a=13, b=0))
        assert adder.handler_errors == 1  # counted and logged server side, the server lives on
        with pytest.raises(ServiceTimeout):
            add.call(AddRequest(a=99, b=0))  # deferred and never answered
        assert add.call(AddRequest(a=1, b=1)).total == 2.0  # the late call did not jam the client
        wrong = c.client("math/add", AddReply, AddReply)  # a client with the wrong request type
        with pytest.raises(BadRequestError, match="takes AddRequest, got AddReply"):
            wrong.call(AddReply(total=1.0))
        with pytest.raises(TypeError):
            add.call(AddReply(total=1.0))  # type: ignore[arg-type]


def test_bad_payload_names_the_field() -> None:
    """A request of the right type name whose field does not validate (what a foreign client could send)."""
    with GraphHarness([(Adder, None)]) as g:
        c = g.add(palpa.Node, name="client")
        replies: list[RawMessage] = []
        c.subscribe_raw(reply_topic("math/add", "foreign1"), replies.append)
        c.publish_raw(request_topic("math/add"), Header(type="AddRequest", seq=7, stamp=0, node="foreign1"),
                      msgspec.msgpack.encode({"a": "one", "b": 2}))
        g.spin()
        assert [(r.header.type, r.header.seq) for r in replies] == [("ServiceFault", 7)]
        fault = msgspec.msgpack.decode(replies[0].payload, type=ServiceFault)
        assert fault.kind == "bad_request" and "$.a" in fault.message


def test_a_request_arriving_again_after_a_later_one_is_not_run_twice() -> None:
    """At most once: a copy of a request that comes back late (an echo through a bridge to another bus, after the
    client's next call) passes the receiver as a publisher's restart; the server must not run it again."""
    with GraphHarness([(Adder, None)]) as g:
        c = g.add(palpa.Node, name="client")
        replies: list[RawMessage] = []
        c.subscribe_raw(reply_topic("math/add", "foreign1.ab"), replies.append)

        def call(client: str, seq: int, a: float) -> None:
            c.publish_raw(request_topic("math/add"), Header(type="AddRequest", seq=seq, stamp=0, node=client),
                          msgspec.msgpack.encode({"a": a, "b": 1.0}))
            g.spin()

        call("foreign1.ab", 1, 1.0)
        call("foreign1.ab", 2, 2.0)
        call("foreign1.ab", 1, 1.0)    # request 1 again, after 2
        call("foreign1.ab", 3, 3.0)
        call("foreign2.cd", 1, 5.0)    # another client's first call: its own numbers
        c.publish_raw(request_topic("math/add"),       # foreign1 restarted (a new incarnation): its call 1 is new
                      Header(type="AddRequest", seq=1, stamp=0, node="foreign1.ab", inc=7),
                      msgspec.msgpack.encode({"a": 6.0, "b": 1.0}))
        g.spin()
        assert [r.header.seq for r in replies] == [1, 2, 3, 1]
        assert [msgspec.msgpack.decode(r.payload, type=AddReply).total for r in replies] == [2.0, 3.0, 4.0, 7.0]
        adder = next(n for n in g.nodes if isinstance(n, Adder))
        assert adder.srv.calls == 5 and adder.srv.repeats == 1


def test_no_server_is_its_own_error_after_the_deadline() -> None:
    with GraphHarness() as g:
        c = g.add(palpa.Node, name="client")
        nobody = c.client("math/nobody", AddRequest, AddReply, timeout_s=0.05)
        assert not nobody.wait_for_service(0.02)
        with pytest.raises(NoServerError, match="no server registered"):
            nobody.call(AddRequest(a=1, b=2))


def test_deferred_reply_and_future_callback() -> None:
    with GraphHarness([(Adder, None)]) as g:
        adder = g.nodes[0]
        assert isinstance(adder, Adder)
        c = g.add(palpa.Node, name="client")
        add = c.client("math/add", AddRequest, AddReply)
        assert add.wait_for_service(1.0)
        seen: list[Future[AddReply]] = []
        fut = add.call_async(AddRequest(a=99, b=1))
        fut.add_done_callback(seen.append)
        g.spin()
        assert not fut.done() and len(adder.held) == 1
        adder.held[0].reply(AddReply(total=100.0))
        g.spin()
        assert fut.done() and seen == [fut] and fut.result().total == 100.0


class Echo(palpa.Node):
    """Serves 'me/add' and calls it itself from a timer, and calls a service of a node that calls it back."""

    def setup(self) -> None:
        self.service("me/add", AddRequest, AddReply, lambda r: AddReply(total=r.a + r.b))
        self.service("me/double", AddRequest, AddReply, self.on_double)
        self.own = self.client("me/add", AddRequest, AddReply, timeout_s=2.0)
        self.bounce = self.client("other/bounce", AddRequest, AddReply, timeout_s=2.0)
        self.out: list[float] = []
        self.timer(0.1, self.tick)

    def on_double(self, r: AddRequest) -> AddReply:
        return AddReply(total=2 * r.a)

    def tick(self) -> None:
        self.out.append(self.own.call(AddRequest(a=1, b=2)).total)
        self.out.append(self.bounce.call(AddRequest(a=5, b=0)).total)


class Bouncer(palpa.Node):
    """Answers other/bounce by calling the caller's me/double from inside its handler (a call back)."""

    def setup(self) -> None:
        self.double = self.client("me/double", AddRequest, AddReply, timeout_s=2.0)
        self.service("other/bounce", AddRequest, AddReply, self.on_bounce)

    def on_bounce(self, r: AddRequest) -> AddReply:
        return AddReply(total=self.double.call(r).total + 1)


def test_own_service_and_call_back_from_inside_callbacks_do_not_deadlock() -> None:
    with GraphHarness([(Echo, None), (Bouncer, None)]) as g:
        echo = g.nodes[0]
        assert isinstance(echo, Echo)
        g.advance(0.25)
        assert echo.out == [3.0, 11.0, 3.0, 11.0]
        assert echo.handler_errors == 0


def test_a_timer_is_not_reentered_while_it_waits() -> None:
    """A 10 ms timer that waits 150 ms (wall clock) on a service that never answers: its period passes many times
    during the wait, and still it runs once at a time, and the node's other timer keeps running meanwhile."""
    calls: list[int] = []
    others: list[int] = []

    class Slow(palpa.Node):
        def setup(self) -> None:
            self.srv = self.service("slow/op", AddRequest, AddReply, self.on_op)
            self.c = self.client("slow/op", AddRequest, AddReply, timeout_s=0.15)
            self.timer(0.01, self.tick, first_in_s=0.0)
            self.timer(0.01, lambda: others.append(1))

        def on_op(self, r: AddRequest) -> Responder[AddReply]:
            return self.srv.defer()  # never answered: the caller waits its whole deadline

        def tick(self) -> None:
            calls.append(1)
            with pytest.raises(ServiceTimeout):
                self.c.call(AddRequest(a=1, b=1))

    with Slow(name="slow", transport=MemoryBus().transport(), heartbeat_s=0) as node:
        node.spin_once(0)
        assert calls == [1] and len(others) >= 5


def test_an_executor_of_several_nodes_in_one_thread_lends_its_loop_to_a_waiting_call() -> None:
    """Two nodes spun by one loop (in-process composition): the caller's wait spins the server through the pump
    the executor registered; without one the call could only time out."""
    bus = MemoryBus()  # no harness: nothing else would spin the server
    server = Adder(name="adder", transport=bus.transport(), heartbeat_s=0)
    caller = palpa.Node(name="caller", transport=bus.transport(), heartbeat_s=0)
    add = caller.client("math/add", AddRequest, AddReply, timeout_s=0.2)
    server.spin_once(0)
    caller.spin_once(0)
    with pytest.raises(ServiceTimeout):
        add.call(AddRequest(a=1, b=1))
    set_wait_pump(caller, lambda: server.spin_once(0))
    assert add.call(AddRequest(a=1, b=1)).total == 2.0
    server.close(0)
    caller.close(0)


def test_a_handler_waiting_on_a_call_can_defer_after_a_nested_request_of_its_own_service() -> None:
    """Request 1's handler calls another service, which calls this service again (request 2, answered at once);
    back in request 1's handler, defer() still answers request 1."""

    class Relay(palpa.Node):
        def setup(self) -> None:
            self.held: list[Responder[AddReply]] = []
            self.srv = self.service("relay/add", AddRequest, AddReply, self.on_add)
            self.peer = self.client("peer/add", AddRequest, AddReply, timeout_s=2.0)

        def on_add(self, r: AddRequest) -> AddReply | Responder[AddReply]:
            if r.a == 0:
                return AddReply(total=r.b)
            inner = self.peer.call(AddRequest(a=0, b=r.b))  # the peer calls relay/add(a=0) meanwhile
            responder = self.srv.defer()
            self.held.append(responder)
            responder.reply(AddReply(total=r.a + inner.total))
            return responder

    class Peer(palpa.Node):
        def setup(self) -> None:
            self.relay = self.client("relay/add", AddRequest, AddReply, timeout_s=2.0)
            self.service("peer/add", AddRequest, AddReply, lambda r: self.relay.call(r))

    with GraphHarness([(Relay, None), (Peer, None)]) as g:
        c = g.add(palpa.Node, name="client").client("relay/add", AddRequest, AddReply, timeout_s=2.0)
        fut = c.call_async(AddRequest(a=5, b=2))
        g.spin()
        assert fut.result().total == 7.0
        assert g.nodes[0].handler_errors == 0
