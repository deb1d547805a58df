"""What a node needs from a transport (:class:`Transport`), and what every transport hands it (:class:`Delivery`).

:class:`palpa.net.transport.ZmqTransport` is the transport over ZeroMQ sockets; :class:`palpa.net.memory.MemoryBus`
provides an in-memory one. Both deliver the frames of one envelope ``[topic, header, payload, *blobs]`` and whether
it came from the latched cache.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import msgspec

from palpa.net.wire import Envelope

__all__ = ["Delivery", "SendFn", "Transport"]

SendFn = Callable[[Sequence[bytes], bool], None]
"""Sends one envelope's frames; the bool says whether the topic is latched."""


class Delivery(msgspec.Struct, gc=False):
    """One envelope as received (a Struct, not a NamedTuple: made once per message, ~4x cheaper).

    An in-memory bus hands the same Delivery to every node that listens (its frames are never changed); the first
    receiver to parse it keeps the parsed envelope in :attr:`envelope`, and the others take it from there instead of
    parsing the same bytes again (issue 40: a pose on its way to three nodes was parsed three times)."""

    frames: list[bytes]
    from_cache: bool
    envelope: Envelope | None = None
    """The frames parsed (:func:`palpa.net.wire.parse_envelope`), once some receiver did; None before, or when they
    are malformed (each receiver then counts the error itself)."""


class Transport(Protocol):
    """What a node needs from the bus."""

    def send(self, frames: Sequence[bytes], latched: bool) -> None:
        """Publish one envelope through the bus; ``latched`` also stores it as the topic's last value."""
        ...

    def sender(self, topic: bytes, direct: bool | None) -> SendFn:
        """How a publisher of ``topic`` sends: through the bus, or straight to subscribers when ``direct``
        (None: as the transport's options say). Falls back to the bus where direct is not possible."""
        ...

    def has_subscribers(self, topic: bytes) -> bool:
        """True when some subscriber's subscription matches ``topic`` (as far as this transport has heard)."""
        ...

    def subscribe(self, prefix: bytes, request_latched: bool, wants: Callable[[str], bool] | None = None) -> None:
        """Receive envelopes whose topic starts with ``prefix``; optionally ask the cache for its last value.
        ``wants``: which of those topics are taken (the rest may still be delivered), so that no connection is made
        to a direct publisher (palpa.net.direct) for a topic no one here takes."""
        ...

    def unsubscribe(self, prefix: bytes) -> None: ...

    def poll(self, timeout_s: float) -> list[Delivery]:
        """Wait up to ``timeout_s`` for envelopes and return every one that is ready (maybe none)."""
        ...

    def close(self, linger_ms: int) -> None: ...
