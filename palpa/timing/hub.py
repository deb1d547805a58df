"""The composition's in-memory bus and its one bridge to the real bus (palpa.timing.compose): what the composed
nodes publish goes to each other in memory and, when someone outside listens (or the topic is latched), out through
the bridge; the bridge subscribes outside to what they want and do not publish themselves."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from palpa.net.memory import MemoryBus, MemoryTransport
from palpa.net.transport import SendFn, Transport

__all__ = ["HubBus", "HubTransport"]


class HubBus(MemoryBus):
    """The composed nodes' in-memory bus; what they publish also leaves through the bridge to the real bus.

    The bridge subscribes on the real bus to the exact topics the composed nodes subscribe to and do not publish
    themselves: a topic published inside is the composition's own (taking it from outside as well would bring every
    message back through the proxy, doubling the traffic), and a catch-all prefix inside (the recorder's) hears the
    composition only."""

    def __init__(self, bridge: Transport | None) -> None:
        super().__init__()
        self.bridge = bridge
        self.published: set[bytes] = set()
        self.wanted: dict[bytes, bool] = {}
        self.outward: set[bytes] = set()
        self._synced = True

    def send_out(self, frames: Sequence[bytes], latched: bool) -> None:
        self._route(list(frames), latched)
        bridge = self.bridge
        # out on the bus only what someone there listens to (a PUB socket drops the rest itself, after its cost to
        # us); a latched value goes to the bus's cache whoever listens
        if bridge is not None and (latched or bridge.has_subscribers(frames[0])):
            bridge.send(frames, latched)

    def transport(self) -> MemoryTransport:
        t = HubTransport(self)
        self._add(t)
        return t

    def note(self, topic: bytes, *, published: bool = False, latched: bool = False) -> None:
        if published:
            self.published.add(topic)
        else:
            self.wanted[topic] = self.wanted.get(topic, False) or latched
        self._synced = False

    def sync_bridge(self) -> None:
        """Subscribe the bridge to what the composed nodes want from outside (and no longer to what they publish)."""
        if self._synced or self.bridge is None:
            return
        self._synced = True
        want = {t for t in self.wanted if t and t not in self.published}
        for topic in want - self.outward:
            self.bridge.subscribe(topic, self.wanted[topic])
        for topic in self.outward - want:
            self.bridge.unsubscribe(topic)
        self.outward = want


class HubTransport(MemoryTransport):
    """A composed node's connection to the hub: its sends go out through :meth:`HubBus.send_out`, and what it
    publishes or subscribes to is noted for the bridge."""

    bus: HubBus

    def send(self, frames: Sequence[bytes], latched: bool) -> None:
        self.bus.send_out(frames, latched)

    def sender(self, topic: bytes, direct: bool | None) -> SendFn:
        self.bus.note(topic, published=True)
        return self.send

    def has_subscribers(self, topic: bytes) -> bool:
        bridge = self.bus.bridge
        return super().has_subscribers(topic) or (bridge is not None and bridge.has_subscribers(topic))

    def subscribe(self, prefix: bytes, request_latched: bool, wants: Callable[[str], bool] | None = None) -> None:
        super().subscribe(prefix, request_latched)
        self.bus.note(prefix, latched=request_latched)
