"""What a node has declared on the bus, by resolved name: its publishers, its subscriptions (typed and raw), its
services, and what it sent raw.

:class:`palpa.node.node.Node` owns one :class:`Inventory` and hands its declarations here (``Node.publisher``,
``Node.subscribe``, ``Node.service``, ...): the rules of declaring live in one place (one publisher per topic and
type, one subscription and one server per name, a message type that is a palpa Message, which topics carry a
simulation's instant). The node's heartbeats (:mod:`palpa.node.presence`) and its lockstep acks
(:mod:`palpa.node.node_time`) read the tables it keeps. Typed subscriptions are kept by the node's
:class:`~palpa.node.receive.Receiver`, which delivers to them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar, cast

from palpa.message import Message
from palpa.net.wire import Header, encode_header
from palpa.node.endpoints import MsgInfo, Publisher, RawMessage, Subscription, handler_type
from palpa.node.naming import RUNTIME_PREFIX
from palpa.node.nodeapi import NodeApi
from palpa.node.receive import Receiver
from palpa.node.service import Responder, Service

__all__ = ["Inventory"]

M = TypeVar("M", bound=Message)
Q = TypeVar("Q", bound=Message)
R = TypeVar("R", bound=Message)


class Inventory:
    """One node's publishers, subscriptions and services, made and registered by name (see the module's doc).

    ``incarnation`` is the node's, written with its name into every header; ``instants``: the node is on a
    simulation clock, and its publishers (those outside ``_palpa/``) say in every header which instant it was at."""

    def __init__(self, node: NodeApi, rx: Receiver, incarnation: int, instants: bool) -> None:
        self._node = node
        self._rx = rx
        self._incarnation = incarnation
        self._instants = instants
        self.pubs: dict[str, Publisher[Any]] = {}
        """The node's publishers by resolved topic."""
        self.services: dict[str, Service[Any, Any]] = {}
        """The services the node serves by resolved name."""
        self.raw_sent: dict[str, int] = {}
        """Messages published with :meth:`publish_raw` per topic (service requests and replies among them)."""

    def service(
        self, name: str, request_type: type[Q], response_type: type[R], handler: Callable[[Q], R | Responder[R]]
    ) -> Service[Q, R]:
        """``Node.service``: serve ``name``, once per node."""
        node = self._node
        if node.resolve(name) in self.services:
            raise ValueError(f"node {node.name!r} already serves {node.resolve(name)!r}")
        srv = self.services[node.resolve(name)] = Service(node, name, request_type, response_type, handler)
        return srv

    def publisher(
        self, topic: str, msg_type: type[M], *, latched: bool = False, batch: int | None = None,
        direct: bool | None = None,
    ) -> Publisher[M]:
        """``Node.publisher``: the topic's publisher, made at the first call and the same at every later one (a
        different type on it is refused)."""
        node = self._node
        resolved = node.resolve(topic)
        existing = self.pubs.get(resolved)
        if existing is not None:
            if existing.type is not msg_type:
                raise TypeError(f"topic {resolved!r} already published as {existing.type.type_name}")
            return existing
        instant = self._instants and not resolved.startswith(RUNTIME_PREFIX)
        pub = Publisher(node.transport, node.clock, node.dispatch, node, (node.name, self._incarnation), resolved,
                        msg_type, latched, batch, direct, instant)
        self.pubs[resolved] = pub
        return pub

    def publish_raw(
        self, topic: str, header: Header, payload: bytes, blobs: Sequence[bytes] = (), *, latched: bool = False
    ) -> None:
        """``Node.publish_raw``: send as given, counted in :attr:`raw_sent` (outside ``_palpa/``)."""
        self._node.transport.send([topic.encode(), encode_header(header), payload, *blobs], latched)
        if not topic.startswith(RUNTIME_PREFIX):
            self.raw_sent[topic] = self.raw_sent.get(topic, 0) + 1

    def subscribe(
        self,
        topic: str,
        type_or_callback: type[M] | Callable[[M], object] | Callable[[M, MsgInfo], object],
        callback: Callable[[M], object] | Callable[[M, MsgInfo], object] | None = None,
        *,
        queue_size: int = 1000,
    ) -> Subscription[M]:
        """``Node.subscribe``: the message type given or read from the callback's annotation, one subscription
        per topic."""
        node = self._node
        if isinstance(type_or_callback, type):
            msg_type: type[Any] = type_or_callback
        else:
            callback = type_or_callback
            msg_type = handler_type(callback)
        if not (isinstance(msg_type, type) and issubclass(msg_type, Message)):
            raise TypeError(f"subscribe({topic!r}): {msg_type!r} is not a palpa Message type")
        resolved = node.resolve(topic)
        key = resolved.encode()
        if key in self._rx.subs:
            raise ValueError(f"node {node.name!r} already subscribes to {resolved!r}")
        sub: Subscription[M] = Subscription(node, resolved, cast("type[M]", msg_type), callback, queue_size)
        self._rx.add(key, sub)
        node.transport.subscribe(key, request_latched=True)
        return sub

    def subscribe_raw(self, prefix: str, callback: Callable[[RawMessage], object], *,
                      topics: Callable[[str], bool] | None = None) -> None:
        """``Node.subscribe_raw``: hand envelopes under ``prefix`` (those on ``topics``) to ``callback``."""
        key = prefix.encode()
        self._rx.add_raw(key, callback, topics)
        self._node.transport.subscribe(key, request_latched=True, wants=topics)
