"""What the runtime's helpers (its inventory, services, service clients, the parameter server) use of a node, as a
Protocol.

They are made by :class:`palpa.node.node.Node` and given the node, but they depend on this surface only, so that
``node.py`` can import them without them importing ``node.py`` back (no import cycle in the core).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

from palpa.message import Message
from palpa.net.transport import Transport
from palpa.net.wire import Header
from palpa.node.dispatch import Dispatch
from palpa.node.endpoints import Publisher, RawMessage, Timer
from palpa.timing.clock import Clock

__all__ = ["NodeApi"]

M = TypeVar("M", bound=Message)


class NodeApi(Protocol):
    """The part of :class:`palpa.node.node.Node` that its inventory, services, clients and the parameter server
    call."""

    name: str
    clock: Clock
    log: logging.Logger
    dispatch: Dispatch
    refusals: dict[str, int]

    @property
    def transport(self) -> Transport: ...

    @property
    def closed(self) -> bool: ...

    @property
    def is_shutdown(self) -> bool: ...

    def resolve(self, topic: str) -> str: ...

    def instant_ns(self) -> int: ...

    def publisher(
        self, topic: str, msg_type: type[M], *, latched: bool = False, batch: int | None = None,
        direct: bool | None = None,
    ) -> Publisher[M]: ...

    def publish_raw(
        self, topic: str, header: Header, payload: bytes, blobs: Sequence[bytes] = (), *, latched: bool = False
    ) -> None: ...

    def subscribe_raw(self, prefix: str, callback: Callable[[RawMessage], object]) -> None: ...

    def timer(
        self, period_s: float, callback: Callable[[], object], *, oneshot: bool = False,
        first_in_s: float | None = None,
    ) -> Timer: ...

    def service(self, name: str, request_type: type[Any], response_type: type[Any],
                handler: Callable[[Any], Any]) -> object: ...

    def spin_once(self, timeout_s: float = 0.0) -> None: ...

    def flush(self) -> None: ...
