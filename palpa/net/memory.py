"""An in-memory bus: envelopes routed between transports in one process, with ZeroMQ's prefix semantics and a
latched cache, and no sockets. :class:`palpa.timing.compose.Composition` runs a simulated graph on it (``palpa launch
--in-process``); the test harnesses of :mod:`palpa.testing` drive nodes on it.

A bus address ``memq://NAME`` (as LCM's) names one of these in the process: a node built with ``bus="memq://NAME"``
(or under ``PALPA_BUS=memq://NAME``) joins :func:`named_bus` ``(NAME)``, where an executor built on that bus (a
``Composition(bus=named_bus(NAME))``, a ``GraphHarness(bus=named_bus(NAME))``) runs it with the others."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence

from palpa.errors import BusError
from palpa.net.transport_api import Delivery, SendFn

__all__ = ["MEMQ_SCHEME", "MemoryBus", "MemoryTransport", "memq_name", "named_bus"]

MEMQ_SCHEME = "memq://"
_named: dict[str, MemoryBus] = {}


def memq_name(address: str) -> str | None:
    """The bus name of a ``memq://NAME`` address, None for any other address; a :class:`BusError` for
    ``memq://`` without a name."""
    if not address.strip().startswith(MEMQ_SCHEME):
        return None
    name = address.strip()[len(MEMQ_SCHEME):]
    if not name:
        raise BusError(f"bus address {address!r}: memq:// needs a name (memq://NAME: an in-memory bus of this "
                       "process)")
    return name


def named_bus(name: str) -> MemoryBus:
    """The process's in-memory bus called ``name`` (``memq://NAME``), made at its first use."""
    bus = _named.get(name)
    if bus is None:
        bus = _named[name] = MemoryBus()
    return bus


class MemoryBus:
    """Routes envelopes between in-process transports with ZeroMQ's prefix semantics and a latched cache."""

    def __init__(self) -> None:
        self._transports: list[MemoryTransport] = []
        self._cache: dict[bytes, list[bytes]] = {}
        self._listeners: dict[bytes, list[MemoryTransport]] = {}
        self.pump: Callable[[], None] | None = None
        """Lets the other nodes run while one waits on a service call (set by the executor: a
        :class:`~palpa.timing.compose.Composition`, a :class:`~palpa.testing.GraphHarness`)."""

    def transport(self) -> MemoryTransport:
        t = MemoryTransport(self)
        self._add(t)
        return t

    def _add(self, t: MemoryTransport) -> None:
        self._transports.append(t)
        self.changed()

    def changed(self) -> None:
        """Forget who listens to what (a transport subscribed, unsubscribed or closed)."""
        self._listeners.clear()

    def route(self, frames: Sequence[bytes]) -> None:
        """Deliver one envelope (any frames, malformed ones included) as a publisher on this bus would."""
        self._route([bytes(f) for f in frames], False)

    def _route(self, frames: list[bytes], latched: bool) -> None:
        if latched:
            self._cache[frames[0]] = frames[1:]
        delivery = Delivery(frames, False)  # one for every listener: the first to parse it parses it for all
        for t in self.listeners(frames[0]):
            t.inbox.append(delivery)

    def listeners(self, topic: bytes) -> list[MemoryTransport]:
        """The open transports with a subscription matching ``topic`` (ZeroMQ's prefix rule)."""
        found = self._listeners.get(topic)
        if found is None:
            found = self._listeners[topic] = [t for t in self._transports
                                              if not t.closed and any(topic.startswith(p) for p in t.prefixes)]
        return found

    def pending(self) -> bool:
        return any(t.inbox for t in self._transports if not t.closed)


class MemoryTransport:
    """One node's connection to a :class:`MemoryBus`."""

    def __init__(self, bus: MemoryBus) -> None:
        self.bus = bus
        self.prefixes: list[bytes] = []
        self.inbox: deque[Delivery] = deque()
        self.closed = False

    def send(self, frames: Sequence[bytes], latched: bool) -> None:
        self.bus._route([bytes(f) for f in frames], latched)

    def sender(self, topic: bytes, direct: bool | None) -> SendFn:
        return self.send  # in memory every topic is direct

    def has_subscribers(self, topic: bytes) -> bool:
        return bool(self.bus.listeners(topic))

    def subscribe(self, prefix: bytes, request_latched: bool, wants: Callable[[str], bool] | None = None) -> None:
        self.prefixes.append(prefix)
        self.bus.changed()
        if request_latched:
            for topic, rest in self.bus._cache.items():
                if topic.startswith(prefix):
                    self.inbox.append(Delivery([topic, *rest], True))

    def unsubscribe(self, prefix: bytes) -> None:
        if prefix in self.prefixes:
            self.prefixes.remove(prefix)
            self.bus.changed()

    def pump(self) -> None:
        """Run the rest of the graph once (a node blocked in a service call waits for the others this way)."""
        if self.bus.pump is not None:
            self.bus.pump()

    def poll(self, timeout_s: float) -> list[Delivery]:
        out = list(self.inbox)
        self.inbox.clear()
        return out

    def close(self, linger_ms: int) -> None:
        self.closed = True
        self.bus.changed()
