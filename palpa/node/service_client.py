"""The caller side of services: :class:`Client` (made by ``Node.client``), :class:`Future`, :func:`discover`.

A blocking :meth:`Client.call` waits by spinning its node (``spin_once``), so the node keeps dispatching its input
while it waits: its own services, other topics, timers (a timer is never re-entered). That is why a call from any
callback completes, including a call to a service of the same node or of a node that calls back (the deadlock of
rclpy's single-threaded executor, rclpy #1398 and #1181, cannot happen). On the in-memory bus
(:mod:`palpa.testing`) the wait also runs the harness's other nodes. Every call has a deadline, on the node's clock
(:class:`palpa.timing.clock.Deadline`): simulated time when the node runs on it.
"""

from __future__ import annotations

import contextlib
import secrets
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import msgspec

from palpa.message import Message
from palpa.net.wire import DECODE_ERRORS, Header
from palpa.node.endpoints import RawMessage, Timer
from palpa.node.service import (
    DEFAULT_TIMEOUT_S,
    ENCODER,
    FAULTS,
    SERVICE_INFO_PREFIX,
    HandlerError,
    NoServerError,
    ServiceError,
    ServiceFault,
    ServiceInfo,
    ServiceTimeout,
    reply_topic,
    request_topic,
)
from palpa.timing.clock import Deadline

if TYPE_CHECKING:
    from palpa.node.nodeapi import NodeApi

__all__ = ["Client", "Future", "discover", "set_wait_pump"]

Q = TypeVar("Q", bound=Message)
R = TypeVar("R", bound=Message)

_MAX_NESTED_WAITS = 16
_EXPIRY_PERIOD_S = 0.01
_info_decoder = msgspec.msgpack.Decoder(ServiceInfo)
_fault_decoder = msgspec.msgpack.Decoder(ServiceFault)
_wait_depth: weakref.WeakKeyDictionary[NodeApi, int] = weakref.WeakKeyDictionary()
# what each node has heard of servers: a second client of a service in one node is not replayed the cached
# announcement (the node's receiver drops what it has already delivered), so it starts from here
_directory: weakref.WeakKeyDictionary[NodeApi, dict[str, ServiceInfo]] = weakref.WeakKeyDictionary()
_pumps: weakref.WeakKeyDictionary[NodeApi, Callable[[], None]] = weakref.WeakKeyDictionary()


def set_wait_pump(node: NodeApi, pump: Callable[[], None]) -> None:
    """For an executor that runs several nodes in one thread (in-process composition): while ``node`` waits in a
    blocking call, also call ``pump()``, which must spin the executor's other nodes once; otherwise the node would
    wait for a server it keeps from running. (:class:`palpa.testing.GraphHarness` does this through its bus.)"""
    _pumps[node] = pump


def _pump_of(node: NodeApi) -> Callable[[], None] | None:
    pump = _pumps.get(node)
    return pump if pump is not None else getattr(node.transport, "pump", None)


class Future(Generic[R]):
    """The outcome of one :meth:`Client.call_async`: poll :meth:`done`, add a callback, or wait with
    :meth:`result` (which keeps the node dispatching)."""

    def __init__(self, client: Client[Any, R], seq: int, deadline: Deadline) -> None:
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
            self._client.node.dispatch.call(fn, self)
        else:
            self._callbacks.append(fn)

    def result(self, timeout_s: float | None = None) -> R:
        """Wait (dispatching the node's input meanwhile) and return the response, or raise the call's
        :class:`ServiceError`. ``timeout_s`` bounds this wait only; the call's own deadline still applies."""
        node = self._client.node
        limit = Deadline(node.clock, timeout_s)  # None: only the call's own deadline ends the wait
        depth = _wait_depth.get(node, 0)
        if not self._done and depth >= _MAX_NESTED_WAITS:
            raise ServiceError(f"{depth} blocking service calls are already waiting in node {node.name!r}; "
                               "use call_async from callbacks")
        _wait_depth[node] = depth + 1
        pump = _pump_of(node)
        try:
            while not self._done:
                self._client._expire(self)
                if self._done or limit.passed():
                    break
                node.flush()
                node.spin_once(min(0.05, limit.remaining_s(), self.deadline.remaining_s()))
                if pump is not None:
                    pump()
        finally:
            _wait_depth[node] = depth
        if not self._done:
            raise ServiceTimeout(f"service {self._client.name!r}: no reply within {timeout_s} s of waiting")
        if self._error is not None:
            raise self._error
        assert self._value is not None
        return self._value

    def _finish(self, value: R | None, error: ServiceError | None) -> None:
        if self._done:
            return
        self._value, self._error, self._done = value, error, True
        for fn in self._callbacks:
            self._client.node.dispatch.call(fn, self)
        self._callbacks.clear()


class Client(Generic[Q, R]):
    """The caller side of a service. Made by ``Node.client``; ``call`` blocks (without blocking the node),
    ``call_async`` returns a :class:`Future`."""

    def __init__(self, node: NodeApi, name: str, request_type: type[Q], response_type: type[R], *,
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
        self._timer: Timer | None = None
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
        t = self.node.transport
        return self.server is not None and self.server.alive and t.has_subscribers(self._req_topic_b) \
            and t.has_subscribers(self._reply_topic_b)

    def wait_for_service(self, timeout_s: float = DEFAULT_TIMEOUT_S) -> bool:
        """Spin the node until :meth:`ready` or ``timeout_s`` passes; returns :meth:`ready`."""
        deadline = Deadline(self.node.clock, timeout_s)
        pump = _pump_of(self.node)
        while not self.ready() and not deadline.passed() and not self.node.is_shutdown:
            self.node.spin_once(min(0.01, deadline.remaining_s()))
            if pump is not None:
                pump()
        return self.ready()

    def _on_info(self, raw: RawMessage) -> None:
        if raw.topic != self._info_topic or raw.header.type != ServiceInfo.type_name:
            return
        try:
            self._known[self.name] = _info_decoder.decode(raw.payload)
        except DECODE_ERRORS:
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
        fut: Future[R] = Future(self, seq, Deadline(self.node.clock, self.timeout_s if timeout_s is None else timeout_s))
        self._pending[seq] = fut
        self._unsent[seq] = ENCODER.encode(request)
        self._send_unsent()
        if self._timer is None:
            self._timer = self.node.timer(_EXPIRY_PERIOD_S, self._tick)
        return fut

    def _send_unsent(self) -> None:
        if not self._unsent or not self.ready():
            return
        node = self.node
        for seq, payload in sorted(self._unsent.items()):
            header = Header(type=self.request_type.type_name, seq=seq, stamp=node.clock.now_ns(), node=self.id,
                            at=node.instant_ns())
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
                err = FAULTS.get(fault.kind, HandlerError)
                fut._finish(None, err(f"service {self.name!r}: {fault.message}"))
            elif raw.header.type == self.response_type.type_name:
                fut._finish(self._decoder.decode(raw.payload), None)
            else:
                fut._finish(None, HandlerError(f"service {self.name!r} replied {raw.header.type}, "
                                               f"expected {self.response_type.type_name}"))
        except DECODE_ERRORS as exc:
            fut._finish(None, HandlerError(f"service {self.name!r}: undecodable reply: {exc}"))

    def _tick(self) -> None:
        self._expire()

    def _expire(self, waited: Future[Any] | None = None) -> None:
        """End the pending calls whose deadline has come. ``waited``: the call a blocking wait is in, the only one
        whose deadline counts this round (a clock that stands still ends that wait after its rounds, not the other
        calls', whose time has not come)."""
        self._send_unsent()
        for seq, fut in list(self._pending.items()):
            if not (fut.deadline.passed() if fut is waited else fut.deadline.reached()):
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


def discover(node: NodeApi, name: str, wait_s: float) -> ServiceInfo:
    """The live server of ``name`` as the bus's last-value cache announces it (a tool that does not know the
    response type yet asks this first); :class:`NoServerError` when none is announced within ``wait_s``."""
    topic = SERVICE_INFO_PREFIX + name
    known = _directory.setdefault(node, {})

    def on_info(raw: RawMessage) -> None:
        if raw.topic == topic and raw.header.type == ServiceInfo.type_name:
            with contextlib.suppress(*DECODE_ERRORS):
                known[name] = _info_decoder.decode(raw.payload)

    node.subscribe_raw(topic, on_info)
    deadline = Deadline(node.clock, wait_s)
    while not (name in known and known[name].alive) and not deadline.passed():
        node.spin_once(min(0.02, deadline.remaining_s()))
    info = known.get(name)
    if info is None or not info.alive:
        why = "its server has closed" if info is not None else "no server announced it"
        raise NoServerError(f"service {name!r}: {why} within {wait_s:g} s (`palpa service list` shows what runs)")
    return info
