"""Services: typed request/reply between nodes, over the same bus as topics (wire protocol in docs/wire.md).

    class Scanner(Node):
        def setup(self) -> None:
            self.service("scanner/probe_at", ProbeAt, ProbeResult, self.on_probe)

    class Operator(Node):
        def setup(self) -> None:
            self.probe = self.client("scanner/probe_at", ProbeAt, ProbeResult)

        def on_click(self, msg: Click) -> None:
            result = self.probe.call(ProbeAt(x_mm=msg.x, y_mm=msg.y), timeout_s=30.0)   # blocking, or:
            self.probe.call_async(ProbeAt(x_mm=msg.x, y_mm=msg.y)).add_done_callback(self.on_result)

A request travels on topic ``<name>/request`` with the caller's client id as the header's ``node`` and the call
number as its ``seq``; the reply (the response type, or a :class:`ServiceFault`) comes back on
``<name>/reply/<client id>`` with the same ``seq``. A server announces itself on the latched topic
``_palpa/srv/<name>`` (the bus's last-value cache is the directory) and in its node's heartbeat.

No deadlock, from anywhere: a blocking :meth:`Client.call` keeps the node dispatching while it waits (its own
service requests, other topics, timers), so a callback may call a service of another node, of a node that calls
back, or of its own node. A timer never re-enters itself while it waits; a subscription callback can be handed the
next message of its topic during a blocking call (as an ``await`` would) — use :meth:`Client.call_async` where that
matters. A handler that cannot answer at once (a probe that moves the arm) returns :meth:`Service.defer`'s
:class:`Responder` and answers later; the node keeps running meanwhile.
"""

from __future__ import annotations

import contextlib
import secrets
import time
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import msgspec

from palpa.endpoints import RawMessage
from palpa.errors import PalpaError, ParamError
from palpa.message import Message
from palpa.wire import Header

if TYPE_CHECKING:
    from palpa.node import Node

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "SERVICE_INFO_PREFIX",
    "BadRequestError",
    "Client",
    "Future",
    "HandlerError",
    "NoServerError",
    "RequestRefused",
    "Responder",
    "Service",
    "ServiceError",
    "ServiceFault",
    "ServiceInfo",
    "ServiceTimeout",
    "discover",
    "reply_topic",
    "request_topic",
]

Q = TypeVar("Q", bound=Message)
R = TypeVar("R", bound=Message)

DEFAULT_TIMEOUT_S = 5.0
"""How long a call waits for its reply unless told otherwise (a call never waits forever)."""
SERVICE_INFO_PREFIX = "_palpa/srv/"
_MAX_NESTED_WAITS = 16
_EXPIRY_PERIOD_S = 0.01


class ServiceError(PalpaError):
    """Base of every failed service call."""


class NoServerError(ServiceError):
    """No server of the service was found on the bus before the call's deadline."""


class ServiceTimeout(ServiceError, TimeoutError):
    """The server was there but no reply came before the deadline."""


class BadRequestError(ServiceError):
    """The server could not decode or validate the request (the message names the field); a handler raises it (or
    :class:`palpa.ParamError`) to reject a request that is malformed."""


class RequestRefused(ServiceError):
    """The server understood the request and said no (a set-point above the cap, a parameter change its node
    refuses); a handler raises it with the reason."""


class HandlerError(ServiceError):
    """The server's handler raised an unexpected exception (its type and text are in the message)."""


class ServiceInfo(Message, frozen=True, kw_only=True):
    """A server's announcement, latched on ``_palpa/srv/<name>``; ``alive=False`` once it closed."""

    name: str
    node: str
    request_type: str
    response_type: str
    alive: bool = True


class ServiceFault(Message, frozen=True, kw_only=True):
    """The reply of a failed call: ``kind`` is ``bad_request``, ``refused`` or ``handler_error``."""

    kind: str
    message: str


_FAULTS: dict[str, type[ServiceError]] = {
    "bad_request": BadRequestError, "refused": RequestRefused, "handler_error": HandlerError,
}
_encoder = msgspec.msgpack.Encoder()
_info_decoder = msgspec.msgpack.Decoder(ServiceInfo)
_fault_decoder = msgspec.msgpack.Decoder(ServiceFault)
_wait_depth: weakref.WeakKeyDictionary[Node, int] = weakref.WeakKeyDictionary()
# what each node has heard of servers: a second client of a service in one node is not replayed the cached
# announcement (the node's receiver drops what it has already delivered), so it starts from here
_directory: weakref.WeakKeyDictionary[Node, dict[str, ServiceInfo]] = weakref.WeakKeyDictionary()


def request_topic(name: str) -> str:
    """The topic requests to service ``name`` travel on."""
    return f"{name}/request"


def reply_topic(name: str, client_id: str) -> str:
    """The topic replies to client ``client_id`` of service ``name`` travel on."""
    return f"{name}/reply/{client_id}"


class Responder(Generic[R]):
    """Answers one request, once: now (the handler returned a response) or later (the handler returned this)."""

    def __init__(self, service: Service[Any, R], client_id: str, seq: int) -> None:
        self._service = service
        self.client_id = client_id
        self.seq = seq
        self.done = False

    def reply(self, response: R) -> None:
        """Send the response (a second answer to the same request is ignored)."""
        if not isinstance(response, self._service.response_type):
            raise TypeError(f"service {self._service.name!r} answers {self._service.response_type.type_name}, "
                            f"not {type(response).__name__}")
        self._send(self._service.response_type.type_name, _encoder.encode(response))

    def refuse(self, reason: str) -> None:
        """Answer with a refusal (the caller gets :class:`RequestRefused`)."""
        self.fail("refused", reason)

    def fail(self, kind: str, message: str) -> None:
        """Answer with a fault of ``kind`` (``bad_request``, ``refused`` or ``handler_error``)."""
        self._service.faults += 1
        self._send(ServiceFault.type_name, _encoder.encode(ServiceFault(kind=kind, message=message)))

    def _send(self, type_name: str, payload: bytes) -> None:
        if self.done:
            return
        self.done = True
        node = self._service.node
        if node._closed:
            return
        header = Header(type=type_name, seq=self.seq, stamp=node.clock.now_ns(), node=node.name)
        node.publish_raw(reply_topic(self._service.name, self.client_id), header, payload)


class Service(Generic[Q, R]):
    """The server side of a service: decodes requests, runs the handler, sends the reply. Made by
    ``Node.service``."""

    def __init__(self, node: Node, name: str, request_type: type[Q], response_type: type[R],
                 handler: Callable[[Q], R | Responder[R]]) -> None:
        self.node = node
        self.name = node.resolve(name)
        self.request_type = request_type
        self.response_type = response_type
        self.handler = handler
        self.calls = 0
        self.faults = 0
        self._decoder = msgspec.msgpack.Decoder(request_type)
        self._topic = request_topic(self.name)
        self._current: Responder[R] | None = None
        self._deferred = False
        self._info = node.publisher(SERVICE_INFO_PREFIX + self.name, ServiceInfo, latched=True)
        node.subscribe_raw(self._topic, self._on_request)
        self._announce(True)

    @property
    def types(self) -> str:
        """``Request -> Response``, as listed by ``palpa service list``."""
        return f"{self.request_type.type_name} -> {self.response_type.type_name}"

    def _announce(self, alive: bool) -> None:
        self._info.publish(ServiceInfo(name=self.name, node=self.node.name, alive=alive,
                                       request_type=self.request_type.type_name,
                                       response_type=self.response_type.type_name))

    def withdraw(self) -> None:
        """Tell the directory this server is gone (the node does it when it closes)."""
        self._announce(False)

    def defer(self) -> Responder[R]:
        """From inside the handler: answer later. Return the responder and call its ``reply`` when done."""
        if self._current is None:
            raise RuntimeError(f"service {self.name!r}: defer() is only valid inside its handler")
        self._deferred = True
        return self._current

    def _on_request(self, raw: RawMessage) -> None:
        if raw.topic != self._topic or raw.from_cache:
            return
        self.calls += 1
        responder: Responder[R] = Responder(self, raw.header.node, raw.header.seq)
        if raw.header.type != self.request_type.type_name:
            responder.fail("bad_request", f"service {self.name!r} takes {self.request_type.type_name}, "
                                          f"got {raw.header.type}")
            return
        try:
            request = self._decoder.decode(raw.payload)
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            responder.fail("bad_request", f"{self.request_type.type_name}: {exc}")
            return
        self._current, self._deferred = responder, False
        try:
            result = self.handler(request)
        except RequestRefused as exc:
            responder.refuse(str(exc))
        except (BadRequestError, ParamError, msgspec.ValidationError) as exc:
            responder.fail("bad_request", str(exc))
        except Exception as exc:
            self.node._handler_failed(self.handler)
            responder.fail("handler_error", f"{type(exc).__name__}: {exc}")
        else:
            if result is responder or (self._deferred and result is None):
                return
            if isinstance(result, self.response_type):
                responder.reply(result)
            else:
                responder.fail("handler_error", f"the handler returned {type(result).__name__}, "
                                                f"not {self.response_type.type_name}")
        finally:
            self._current = None


class Future(Generic[R]):
    """The outcome of one :meth:`Client.call_async`: poll :meth:`done`, add a callback, or wait with
    :meth:`result` (which keeps the node dispatching)."""

    def __init__(self, client: Client[Any, R], seq: int, deadline: float) -> None:
        self._client = client
        self.seq = seq
        self.deadline = deadline
        self._value: R | None = None
        self._error: ServiceError | None = None
        self._done = False
        self._callbacks: list[Callable[[Future[R]], object]] = []

    def done(self) -> bool:
        return self._done

    def exception(self) -> ServiceError | None:
        """The error of a finished call (None while pending or when it succeeded)."""
        return self._error

    def add_done_callback(self, fn: Callable[[Future[R]], object]) -> None:
        """Call ``fn(future)`` from the node's loop once the call finishes (at once if it already has)."""
        if self._done:
            self._client.node._call(fn, self)
        else:
            self._callbacks.append(fn)

    def result(self, timeout_s: float | None = None) -> R:
        """Wait (dispatching the node's input meanwhile) and return the response, or raise the call's
        :class:`ServiceError`. ``timeout_s`` bounds this wait only; the call's own deadline still applies."""
        node = self._client.node
        limit = time.monotonic() + timeout_s if timeout_s is not None else self.deadline
        depth = _wait_depth.get(node, 0)
        if not self._done and depth >= _MAX_NESTED_WAITS:
            raise ServiceError(f"{depth} blocking service calls are already waiting in node {node.name!r}; "
                               "use call_async from callbacks")
        _wait_depth[node] = depth + 1
        pump = getattr(node._transport, "pump", None)
        try:
            while not self._done:
                now = time.monotonic()
                self._client._expire(now)
                if self._done or now >= limit:
                    break
                node.flush()
                node.spin_once(min(0.05, max(0.0, min(limit, self.deadline) - now)))
                if pump is not None:
                    pump()
        finally:
            _wait_depth[node] = depth
        if not self._done:
            raise ServiceTimeout(f"service {self._client.name!r}: no reply within {timeout_s:g} s of waiting")
        if self._error is not None:
            raise self._error
        assert self._value is not None
        return self._value

    def _finish(self, value: R | None, error: ServiceError | None) -> None:
        if self._done:
            return
        self._value, self._error, self._done = value, error, True
        for fn in self._callbacks:
            self._client.node._call(fn, self)
        self._callbacks.clear()


class Client(Generic[Q, R]):
    """The caller side of a service. Made by ``Node.client``; ``call`` blocks (without blocking the node),
    ``call_async`` returns a :class:`Future`."""

    def __init__(self, node: Node, name: str, request_type: type[Q], response_type: type[R], *,
                 timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        self.node = node
        self.name = node.resolve(name)
        self.request_type = request_type
        self.response_type = response_type
        self.timeout_s = timeout_s
        self.id = f"{node.name}.{secrets.token_hex(4)}"
        self._known = _directory.setdefault(node, {})
        self._seq = 0
        self._pending: dict[int, Future[R]] = {}
        self._unsent: dict[int, bytes] = {}
        self._timer: Any = None
        self._req_topic = request_topic(self.name)
        self._req_topic_b = self._req_topic.encode()
        self._reply_topic = reply_topic(self.name, self.id)
        self._reply_topic_b = self._reply_topic.encode()
        self._info_topic = SERVICE_INFO_PREFIX + self.name
        self._decoder = msgspec.msgpack.Decoder(response_type)
        node.subscribe_raw(self._reply_topic, self._on_reply)
        node.subscribe_raw(self._info_topic, self._on_info)

    # -- discovery ---------------------------------------------------------------------------------
    @property
    def server(self) -> ServiceInfo | None:
        """The latest announcement of the service's server heard by this node (None: never heard of one)."""
        return self._known.get(self.name)

    def ready(self) -> bool:
        """True once a live server is known and both request and reply subscriptions have reached the bus
        (a request sent before that could be lost, so calls wait for it)."""
        t = self.node._transport
        return self.server is not None and self.server.alive and t.has_subscribers(self._req_topic_b) \
            and t.has_subscribers(self._reply_topic_b)

    def wait_for_service(self, timeout_s: float = DEFAULT_TIMEOUT_S) -> bool:
        """Spin the node until :meth:`ready` or ``timeout_s`` passes; returns :meth:`ready`."""
        deadline = time.monotonic() + timeout_s
        pump = getattr(self.node._transport, "pump", None)
        while not self.ready() and time.monotonic() < deadline and not self.node.is_shutdown:
            self.node.spin_once(min(0.01, max(0.0, deadline - time.monotonic())))
            if pump is not None:
                pump()
        return self.ready()

    def _on_info(self, raw: RawMessage) -> None:
        if raw.topic != self._info_topic or raw.header.type != ServiceInfo.type_name:
            return
        try:
            self._known[self.name] = _info_decoder.decode(raw.payload)
        except (msgspec.ValidationError, msgspec.DecodeError):
            return
        self._send_unsent()

    # -- calling -----------------------------------------------------------------------------------
    def call(self, request: Q, timeout_s: float | None = None) -> R:
        """Send ``request`` and wait for the response (default deadline :attr:`timeout_s`); raises a
        :class:`ServiceError`: :class:`NoServerError`, :class:`ServiceTimeout`, :class:`BadRequestError`,
        :class:`RequestRefused` or :class:`HandlerError`. Safe inside callbacks (see the module docstring)."""
        return self.call_async(request, timeout_s).result()

    def call_async(self, request: Q, timeout_s: float | None = None) -> Future[R]:
        """Send ``request`` now (or as soon as the server is found) and return at once; the future finishes
        with the response or a :class:`ServiceError`, at the latest ``timeout_s`` from now."""
        if not isinstance(request, self.request_type):
            raise TypeError(f"service {self.name!r} takes {self.request_type.type_name}, "
                            f"not {type(request).__name__}")
        self._seq += 1
        seq = self._seq
        fut: Future[R] = Future(self, seq, time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s))
        self._pending[seq] = fut
        self._unsent[seq] = _encoder.encode(request)
        self._send_unsent()
        if self._timer is None:
            self._timer = self.node.timer(_EXPIRY_PERIOD_S, self._tick)
        return fut

    def _send_unsent(self) -> None:
        if not self._unsent or not self.ready():
            return
        node = self.node
        for seq, payload in sorted(self._unsent.items()):
            header = Header(type=self.request_type.type_name, seq=seq, stamp=node.clock.now_ns(), node=self.id)
            node.publish_raw(self._req_topic, header, payload)
        self._unsent.clear()

    def _on_reply(self, raw: RawMessage) -> None:
        if raw.topic != self._reply_topic:
            return
        fut = self._pending.pop(raw.header.seq, None)
        if fut is None:
            return  # a reply after its deadline, or a duplicate
        self._unsent.pop(raw.header.seq, None)
        try:
            if raw.header.type == ServiceFault.type_name:
                fault = _fault_decoder.decode(raw.payload)
                err = _FAULTS.get(fault.kind, HandlerError)
                fut._finish(None, err(f"service {self.name!r}: {fault.message}"))
            elif raw.header.type == self.response_type.type_name:
                fut._finish(self._decoder.decode(raw.payload), None)
            else:
                fut._finish(None, HandlerError(f"service {self.name!r} replied {raw.header.type}, "
                                               f"expected {self.response_type.type_name}"))
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            fut._finish(None, HandlerError(f"service {self.name!r}: undecodable reply: {exc}"))

    def _tick(self) -> None:
        self._send_unsent()
        self._expire(time.monotonic())

    def _expire(self, now: float) -> None:
        self._send_unsent()
        for seq, fut in list(self._pending.items()):
            if now < fut.deadline:
                continue
            del self._pending[seq]
            if self._unsent.pop(seq, None) is not None:
                why = "no server registered" if self.server is None or not self.server.alive else \
                    f"server {self.server.node!r} not reachable yet"
                fut._finish(None, NoServerError(f"service {self.name!r}: {why} (is its node running? "
                                                "`palpa service list`)"))
            else:
                by = f" by node {self.server.node!r}" if self.server is not None else ""
                fut._finish(None, ServiceTimeout(f"service {self.name!r}: no reply{by} within the deadline"))
        if not self._pending and self._timer is not None:
            self._timer.cancel()
            self._timer = None


def discover(node: Node, name: str, wait_s: float) -> ServiceInfo:
    """The live server of ``name`` as the bus's last-value cache announces it (a tool that does not know the
    response type yet asks this first); :class:`NoServerError` when none is announced within ``wait_s``."""
    topic = SERVICE_INFO_PREFIX + name
    known = _directory.setdefault(node, {})

    def on_info(raw: RawMessage) -> None:
        if raw.topic == topic and raw.header.type == ServiceInfo.type_name:
            with contextlib.suppress(msgspec.ValidationError, msgspec.DecodeError):
                known[name] = _info_decoder.decode(raw.payload)

    node.subscribe_raw(topic, on_info)
    deadline = time.monotonic() + wait_s
    while not (name in known and known[name].alive) and time.monotonic() < deadline:
        node.spin_once(0.02)
    info = known.get(name)
    if info is None or not info.alive:
        why = "its server has closed" if info is not None else "no server announced it"
        raise NoServerError(f"service {name!r}: {why} within {wait_s:g} s (`palpa service list` shows what runs)")
    return info
