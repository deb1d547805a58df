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

This module is the server side and what both sides share (errors, announcement, topics); the caller side
(``Node.client``) is :mod:`palpa.node.service_client`. No deadlock, from anywhere: a blocking ``Client.call`` keeps the node dispatching while it waits (its own
service requests, other topics, timers), so a callback may call a service of another node, of a node that calls
back, or of its own node. A timer never re-enters itself while it waits; a subscription callback can be handed the
next message of its topic during a blocking call (as an ``await`` would) — use ``Client.call_async`` where that
matters. A handler that cannot answer at once (a probe that moves the arm) returns :meth:`Service.defer`'s
:class:`Responder` and answers later; the node keeps running meanwhile.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import msgspec

from palpa.errors import PalpaError, ParamError
from palpa.message import Message
from palpa.net.wire import Header
from palpa.node.endpoints import RawMessage

if TYPE_CHECKING:
    from palpa.node.nodeapi import NodeApi

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "SERVICE_INFO_PREFIX",
    "BadRequestError",
    "HandlerError",
    "NoServerError",
    "RequestRefused",
    "Responder",
    "Service",
    "ServiceError",
    "ServiceFault",
    "ServiceInfo",
    "ServiceTimeout",
    "reply_topic",
    "request_topic",
]

Q = TypeVar("Q", bound=Message)
R = TypeVar("R", bound=Message)

DEFAULT_TIMEOUT_S = 5.0
"""How long a call waits for its reply unless told otherwise (a call never waits forever)."""
_CLIENTS_REMEMBERED = 4096
"""Clients whose last call number a server keeps (one invented id per garbage request cannot grow it without end)."""
SERVICE_INFO_PREFIX = "_palpa/srv/"


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


FAULTS: dict[str, type[ServiceError]] = {
    "bad_request": BadRequestError, "refused": RequestRefused, "handler_error": HandlerError,
}
ENCODER = msgspec.msgpack.Encoder()


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
        self._send(self._service.response_type.type_name, ENCODER.encode(response))

    def refuse(self, reason: str) -> None:
        """Answer with a refusal (the caller gets :class:`RequestRefused`)."""
        self.fail("refused", reason)

    def fail(self, kind: str, message: str) -> None:
        """Answer with a fault of ``kind`` (``bad_request``, ``refused`` or ``handler_error``)."""
        self._service.faults += not self.done
        self._send(ServiceFault.type_name, ENCODER.encode(ServiceFault(kind=kind, message=message)))

    def _send(self, type_name: str, payload: bytes) -> None:
        if self.done:
            return
        self.done = True
        node = self._service.node
        if node.closed:
            return
        header = Header(type=type_name, seq=self.seq, stamp=node.clock.now_ns(), node=node.name, at=node.instant_ns())
        node.publish_raw(reply_topic(self._service.name, self.client_id), header, payload)


class Service(Generic[Q, R]):
    """The server side of a service: decodes requests, runs the handler, sends the reply. Made by
    ``Node.service``."""

    def __init__(self, node: NodeApi, name: str, request_type: type[Q], response_type: type[R],
                 handler: Callable[[Q], R | Responder[R]]) -> None:
        self.node = node
        self.name = node.resolve(name)
        self.request_type = request_type
        self.response_type = response_type
        self.handler = handler
        self.calls = 0
        self.faults = 0
        self.repeats = 0
        """Requests not run because their client's sequence number was not past the last one run (at most once)."""
        self._last_seq: dict[tuple[str, int], int] = {}
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
        # at most once: a client numbers its calls 1, 2, 3 ... under an id of its own (docs/wire.md), so a request
        # numbered at or below the last one run from that client is a copy (an echo of it, late, through a bridge
        # to another bus), never a new call; run again it would move a robot twice. A foreign client that keeps
        # its id across restarts tells them apart by its header's incarnation.
        client, seq = (raw.header.node, raw.header.inc), raw.header.seq
        last = self._last_seq.get(client)
        if last is not None and seq <= last:
            self.repeats += 1
            self.node.log.warning("service %r: request %d from %s again after %d: not run twice", self.name, seq,
                                  client[0], last)
            return
        if last is None and len(self._last_seq) >= _CLIENTS_REMEMBERED:
            del self._last_seq[next(iter(self._last_seq))]   # the longest-known client: ids are never reused
        self._last_seq[client] = seq
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
        # a handler waiting on a blocking call may see this service handle another request meanwhile
        outer = self._current, self._deferred
        self._current, self._deferred = responder, False
        try:
            result = self.handler(request)
        except RequestRefused as exc:
            responder.refuse(str(exc))
        except (BadRequestError, ParamError, msgspec.ValidationError) as exc:
            responder.fail("bad_request", str(exc))
        except Exception as exc:
            self.node.dispatch.failed(self.handler)
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
            self._current, self._deferred = outer
