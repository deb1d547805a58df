"""The Foxglove bridge node: every topic on the bus, live in the Foxglove app (``palpa viz``, or ``viz:`` in a
launch file).

It subscribes to every topic (or those ``topics``/``exclude`` pick, as regexes over whole names, like the
recorder), advertises each (topic, type) as a Foxglove channel with the type's JSON Schema, and sends the
payloads as JSON. Latched topics (declared by their publisher, or cached by the bus) are sent again to a client
that subscribes late, so a viewer that joins mid-scan sees the map and the plan at once. The bus side only
appends to a bounded queue (see :mod:`palpa.viz.server`): a slow or stalled client costs the graph nothing.

It binds to loopback unless ``allow_remote`` is set: the Foxglove WebSocket protocol has no authentication, so
anyone who can reach the port sees everything on the bus (and may publish the topics in ``client_publish``).

Clients may publish only the topics listed in ``client_publish`` (e.g. ``robot/estop``), as JSON of the topic's
palpa type; a missing ``stamp_ns`` field is filled with the time of arrival. Services and parameters: a later
server can add them through :meth:`Bridge.services` (empty here), without touching the data path.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import foxglove
import msgspec

import palpa
from palpa import env as palpa_env
from palpa.errors import ParamError, RegistryError
from palpa.message import Message, lookup
from palpa.net.address import is_loopback_host
from palpa.node.node import Node, Publisher, RawMessage
from palpa.node.params import convert_params
from palpa.record.format import TopicFilter, import_message_modules
from palpa.runtime_msgs import LOG_TOPIC
from palpa.viz.server import SUBPROTOCOL, Key, SdkServer

__all__ = ["Bridge", "BridgeParams"]

_ADDRESS_FILE = "viz.address"


class BridgeParams(palpa.Params):
    """Parameters of :class:`Bridge`."""

    host: str = "127.0.0.1"
    """Interface to listen on; anything but loopback needs ``allow_remote``."""
    port: Annotated[int, msgspec.Meta(ge=0, le=65535)] = 8765
    """TCP port (8765 is what the Foxglove app proposes); 0: the OS chooses (printed, and in viz.address)."""
    allow_remote: bool = False
    """Listen beyond loopback: anyone who can reach the port sees the whole bus. Logs a warning."""
    topics: list[str] = []
    """Regexes over whole topic names; empty: every topic (runtime ``_palpa/...`` ones only if named)."""
    exclude: list[str] = []
    client_publish: list[str] = []
    """Topics a client may publish (exact names, e.g. ``robot/estop``); empty: no client publishing."""
    queue_size: Annotated[int, msgspec.Meta(gt=0)] = 10_000
    """Messages between the bus and the sender thread before new ones are dropped (and counted)."""
    backlog: Annotated[int, msgspec.Meta(gt=0)] = 1024
    """Messages the SDK queues per client before dropping that client's oldest."""


class Bridge(Node):
    """Serves the bus to Foxglove over its WebSocket protocol (see the module docstring)."""

    Params = BridgeParams
    params: BridgeParams

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | BridgeParams | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # its timers serve clients in wall time, whatever clock the graph keeps
        where = f"node {name or 'viz'!r}"
        p = convert_params(BridgeParams, params, where=where)
        if not is_loopback_host(p.host) and not p.allow_remote:
            raise ParamError(f"{where}: refusing to listen on {p.host}: the Foxglove protocol has no "
                             "authentication; set allow_remote (palpa viz --allow-remote) to listen beyond "
                             "loopback")
        try:
            self._filter = TopicFilter(p.topics, p.exclude, always=(LOG_TOPIC,))
        except palpa.PalpaError as exc:
            raise ParamError(f"{where}: {exc}") from None
        super().__init__(name or "viz", p, **kwargs)

    def setup(self) -> None:
        p = self.params
        import_message_modules()
        self._latched: dict[Key, tuple[bytes, int]] = {}
        self._bus_latched: set[str] = set()
        self._inbox: deque[tuple[int, str, str, bytes]] = deque()
        self._client_pubs: dict[str, Publisher[Any]] = {}
        self.client_errors = 0
        self.server = SdkServer(
            host=p.host, port=p.port, queue_size=p.queue_size, backlog=p.backlog, name=f"palpa {self.name}",
            latched=self._latched.get, on_client_message=self._client_message,
            client_topics=frozenset(p.client_publish), services=self.services())
        self.port = self.server.port
        self.url = f"ws://{p.host}:{self.port}"
        if not is_loopback_host(p.host):
            self.log.warning("listening on %s beyond loopback: anyone who can reach it sees the whole bus%s",
                             self.url, " and may publish " + ", ".join(p.client_publish) if p.client_publish
                             else "")
        self._write_address()
        self.subscribe_raw("", self._on_raw)
        if p.client_publish:
            self.timer(0.02, self._drain_inbox)
        print(f"palpa viz ready {self.url} (subprotocol {SUBPROTOCOL})", flush=True)

    def _write_address(self) -> None:
        run_dir = palpa_env.get(palpa_env.RUN_DIR)
        if run_dir and Path(run_dir).is_dir():
            try:
                (Path(run_dir) / _ADDRESS_FILE).write_text(self.url + "\n")
            except OSError as exc:
                self.log.warning("cannot write %s: %s", Path(run_dir) / _ADDRESS_FILE, exc)

    def services(self) -> list[foxglove.Service]:
        """Foxglove services to advertise at start (JSON requests; ``Capability.Services`` is offered when there
        are any). None yet: the hook where bus services go once the bus has them. A handler runs on an SDK
        thread, so it must hand its request to the node's thread as :meth:`_client_message` does."""
        return []

    # -- the bus side: constant work per message, never waits on the WebSocket side ----------------------
    def _on_raw(self, raw: RawMessage) -> None:
        topic = raw.topic
        if not self._filter(topic):  # cached per topic
            return
        h = raw.header
        key = (topic, h.type)
        if h.latched or raw.from_cache or topic in self._bus_latched:
            if raw.from_cache:
                self._bus_latched.add(topic)
            self._latched[key] = (raw.payload, h.stamp)
        self.server.offer(key, raw.payload, h.stamp)

    # -- client publishing (SDK threads hand over; the node's thread publishes) --------------------------
    def _client_message(self, client_id: int, topic: str, schema_name: str, data: bytes) -> None:
        self._inbox.append((client_id, topic, schema_name, data))

    def _drain_inbox(self) -> None:
        while self._inbox:
            client_id, topic, schema_name, data = self._inbox.popleft()
            try:
                self._publish_from_client(topic, schema_name, data)
            except (palpa.PalpaError, msgspec.ValidationError, msgspec.DecodeError) as exc:
                self.client_errors += 1
                self.log.warning("client %d: message on %s refused: %s", client_id, topic, exc)

    def _publish_from_client(self, topic: str, schema_name: str, data: bytes) -> None:
        pub = self._client_pubs.get(topic)
        if pub is None:
            cls = self._type_for(topic, schema_name)
            pub = self._client_pubs[topic] = self.publisher("/" + topic, cls)
        fields = msgspec.json.decode(data)
        if not isinstance(fields, dict):
            raise palpa.DecodeError(f"expected a JSON object, got {type(fields).__name__}")
        if "stamp_ns" in pub.type.__struct_fields__ and "stamp_ns" not in fields:
            fields["stamp_ns"] = self.clock.now_ns()
        pub.publish(msgspec.convert(fields, pub.type))

    def _type_for(self, topic: str, schema_name: str) -> type[Message]:
        """The palpa type of a client-published topic: the one it already has on the bus, else the schema name
        the client gave."""
        known = {t for (top, t) in self._latched if top == topic} | {
            t for (top, t, _) in self.server.channels() if top == topic}
        name = next(iter(known)) if len(known) == 1 else schema_name
        try:
            return lookup(name)
        except RegistryError:
            raise palpa.DecodeError(f"topic {topic!r} has no known type (client said {schema_name!r})") from None

    # -- lifecycle ---------------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """The server's counters per topic and per client, plus the bus receive counters (sequence gaps)."""
        out = self.server.stats()
        out["bus"] = {t: s.as_dict() for t, s in self.counters().items() if self._filter(t)}
        out["client_errors"] = self.client_errors
        return out

    def on_shutdown(self) -> None:
        self.server.stop()
        topics = self.server.stats()["topics"]
        dropped = {t: s["dropped"] for t, s in topics.items() if s["dropped"]}
        (self.log.warning if dropped else self.log.info)(
            "foxglove bridge: sent %d messages on %d topics; %s", sum(s["sent"] for s in topics.values()),
            len(topics), f"DROPPED {dropped}" if dropped else "none dropped at the bridge")

