"""The WebSocket side of the Foxglove bridge: one sender thread between a bounded hand-off queue and the
foxglove-sdk server.

The bus side (:class:`palpa.viz.bridge.Bridge`, on the node's thread) only appends to a ``deque`` and never
waits: when the queue is full the message is dropped and counted, for its topic and for every client subscribed
to that topic at that moment. The sender thread turns msgpack payloads into JSON, and only for channels that a
client watches. The SDK's server then queues per client (``backlog`` messages, dropping that client's oldest when
it falls behind) and writes to the sockets on its own threads, so a stalled client holds up neither this thread
nor the graph.

What the SDK (foxglove-sdk 0.30.x) does not expose: how many messages it dropped from one client's queue. The
bridge counts what it handed to each client's subscription (``sent``) and what it dropped before the hand-off
(``dropped``); losses inside the SDK's per-client queue are invisible from Python and are not in these counts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import foxglove
import msgspec
from foxglove.websocket import Capability, ChannelView, Client, ClientChannel, ServerListener

from palpa.errors import PalpaError
from palpa.viz.schema import foxglove_schema

__all__ = ["ClientStats", "SUBPROTOCOL", "SdkServer", "STATS_TOPIC", "TopicStats"]

SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol foxglove-sdk 0.30 speaks (older servers spoke ``foxglove.websocket.v1``)."""
STATS_TOPIC = "_palpa/viz/stats"
"""A channel only the WebSocket clients see: the bridge's counters, once a second."""

log = logging.getLogger("palpa.viz")
_json = msgspec.json.Encoder()
_msgpack = msgspec.msgpack.Decoder()


@dataclass
class TopicStats:
    """Counters of one channel (topic, type) at the bridge."""

    received: int = 0
    """Messages heard on the bus."""
    sent: int = 0
    """Messages transcoded and handed to the SDK while at least one client was subscribed (latched values re-sent
    to late subscribers included)."""
    dropped: int = 0
    """Messages dropped because the hand-off queue was full (the sender thread fell behind)."""
    decode_errors: int = 0


@dataclass
class ClientStats:
    """Counters of one WebSocket client, per topic."""

    address: str = ""
    sent: dict[str, int] = field(default_factory=dict)
    """Messages handed to this client's subscription in the SDK (its own queue may still drop some)."""
    dropped: dict[str, int] = field(default_factory=dict)
    """Messages of a topic this client subscribed to that the bridge dropped before the hand-off."""
    latched_resent: int = 0
    connected: bool = True


class _Channel:
    __slots__ = ("topic", "type_name", "fox", "stats", "clients")

    def __init__(self, topic: str, type_name: str, fox: foxglove.Channel) -> None:
        self.topic = topic
        self.type_name = type_name
        self.fox = fox
        self.stats = TopicStats()
        self.clients: set[int] = set()


Key = tuple[str, str]  # topic, type name


class SdkServer:
    """A foxglove-sdk WebSocket server fed from a bounded queue by one thread. Thread-safe entry points:
    :meth:`offer` (never blocks), :meth:`stats`, :meth:`stop`."""

    def __init__(self, *, host: str, port: int, queue_size: int, backlog: int, name: str,
                 latched: Callable[[Key], tuple[bytes, int] | None],
                 on_client_message: Callable[[int, str, str, bytes], None] | None = None,
                 client_topics: frozenset[str] = frozenset(), services: list[foxglove.Service] | None = None,
                 stats_period_s: float = 1.0) -> None:
        self._queue: deque[tuple[Key, bytes, int]] = deque()
        self._resend: deque[tuple[int, int]] = deque()
        self._queue_size = queue_size
        self._wake = threading.Event()
        self._stopping = False
        self._lock = threading.Lock()  # guards _channels' client sets and _clients (SDK threads write them)
        self._channels: dict[Key, _Channel] = {}
        self._by_id: dict[int, _Channel] = {}
        self._clients: dict[int, ClientStats] = {}
        self._pending: dict[Key, TopicStats] = {}
        self._latched = latched
        self._on_client_message = on_client_message
        self._client_topics = client_topics
        self._client_channels: dict[tuple[int, int], tuple[str, str]] = {}
        self._stats_period_s = stats_period_s
        self._context = foxglove.Context()
        caps = [Capability.ClientPublish] if client_topics and on_client_message else []
        if services:
            caps.append(Capability.Services)
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context, capabilities=caps,
                supported_encodings=["json"] if caps else None, server_listener=_Listener(self),
                services=services or None, message_backlog_size=backlog)
        except RuntimeError as exc:  # the SDK reports an OS error as RuntimeError("FoxgloveError: ...")
            reason = str(exc).removeprefix("FoxgloveError: ")
            hint = " (--port 0, or port: 0 under a launch file's viz:, lets the OS choose a free one)" if "in use" in reason else ""
            raise PalpaError(f"cannot listen on {host}:{port}: {reason}{hint}") from None
        self.port = self._server.port
        self._stats_channel = foxglove.Channel(STATS_TOPIC, message_encoding="json", context=self._context)
        self._thread = threading.Thread(target=self._run, name="palpa-viz-sender", daemon=True)
        self._thread.start()

    # -- the bus side: never blocks ----------------------------------------------------------------------
    def offer(self, key: Key, payload: bytes, stamp_ns: int) -> bool:
        """Queue one message for the clients; False (and counted) when the queue is full."""
        q = self._queue
        if len(q) >= self._queue_size:
            self._count_drop(key)
            return False
        q.append((key, payload, stamp_ns))
        if len(q) == 1:
            self._wake.set()
        return True

    def _count_drop(self, key: Key) -> None:
        chan = self._channels.get(key)
        stats = chan.stats if chan is not None else self._pending.setdefault(key, TopicStats())
        stats.dropped += 1
        if chan is not None and chan.clients:
            with self._lock:
                for cid in chan.clients:
                    c = self._clients.get(cid)
                    if c is not None:
                        c.dropped[key[0]] = c.dropped.get(key[0], 0) + 1

    # -- the sender thread -------------------------------------------------------------------------------
    def _run(self) -> None:
        next_stats = time.monotonic() + self._stats_period_s
        while not self._stopping:
            self._wake.wait(0.05)
            self._wake.clear()
            try:
                while self._resend:
                    self._resend_latched(*self._resend.popleft())
                while self._queue and not self._stopping:
                    key, payload, stamp = self._queue.popleft()
                    self._send(key, payload, stamp)
                if time.monotonic() >= next_stats:
                    next_stats = time.monotonic() + self._stats_period_s
                    if self._stats_channel.has_sinks():
                        self._stats_channel.log(_json.encode(self.stats()))
            except Exception:  # the sender must outlive any one bad message or SDK error
                log.exception("foxglove bridge: sending failed")

    def _channel(self, key: Key) -> _Channel:
        chan = self._channels.get(key)
        if chan is not None:
            return chan
        topic, type_name = key
        data = foxglove_schema(type_name)
        if data is None:
            log.warning("message type %r of topic %r is not importable here: its channel has no schema "
                        "(set PALPA_MESSAGES to the module that defines it)", type_name, topic)
            data = _json.encode({"title": type_name, "type": "object"})
        schema = foxglove.Schema(name=type_name, encoding="jsonschema", data=data)
        fox = foxglove.Channel(topic, schema=schema, message_encoding="json", context=self._context,
                               metadata={"palpa.type": type_name})
        chan = _Channel(topic, type_name, fox)
        with self._lock:
            self._channels[key] = chan
            self._by_id[fox.id()] = chan
        pending = self._pending.pop(key, None)  # drops counted before the channel existed
        if pending is not None:
            chan.stats.dropped += pending.dropped
        return chan

    @staticmethod
    def _log(chan: _Channel, payload: bytes, stamp_ns: int) -> bool:
        """Transcode msgpack -> JSON and hand it to the SDK; False (counted) for a payload that is not msgpack."""
        try:
            data = _json.encode(_msgpack.decode(payload))
        except (msgspec.DecodeError, msgspec.EncodeError, TypeError, ValueError):
            chan.stats.decode_errors += 1
            return False
        chan.fox.log(data, log_time=stamp_ns)
        chan.stats.sent += 1
        return True

    def _send(self, key: Key, payload: bytes, stamp_ns: int) -> None:
        chan = self._channel(key)
        chan.stats.received += 1
        if not chan.clients or not self._log(chan, payload, stamp_ns):
            return
        topic = chan.topic
        with self._lock:
            for cid in chan.clients:
                c = self._clients.get(cid)
                if c is not None:
                    c.sent[topic] = c.sent.get(topic, 0) + 1

    def _resend_latched(self, channel_id: int, client_id: int) -> None:
        chan = self._by_id.get(channel_id)
        value = self._latched((chan.topic, chan.type_name)) if chan is not None else None
        if chan is None or value is None:
            return
        # The SDK's Python API cannot address one client, so every subscriber of this channel gets the latched
        # value again; for a latched topic that is the value it already shows.
        if not self._log(chan, *value):
            return
        with self._lock:
            c = self._clients.get(client_id)
            if c is not None:
                c.latched_resent += 1

    # -- called by the SDK on its threads ----------------------------------------------------------------
    def _subscribed(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._clients.setdefault(client.id, ClientStats(address=f"client {client.id}"))
            chan = self._by_id.get(channel.id)
            if chan is not None:
                chan.clients.add(client.id)
        self._resend.append((channel.id, client.id))
        self._wake.set()

    def _unsubscribed(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            chan = self._by_id.get(channel.id)
            if chan is not None:
                chan.clients.discard(client.id)
                still = any(client.id in c.clients for c in self._channels.values())
                if not still and client.id in self._clients:
                    self._clients[client.id].connected = False

    def _client_advertised(self, client: Client, channel: ClientChannel) -> None:
        if channel.topic not in self._client_topics or channel.encoding != "json":
            log.warning("client %d advertised %r (%s): refused, clients may publish only %s as json",
                        client.id, channel.topic, channel.encoding, ", ".join(sorted(self._client_topics)))
            return
        self._client_channels[(client.id, channel.id)] = (channel.topic, channel.schema_name)

    def _client_data(self, client: Client, channel_id: int, data: bytes) -> None:
        target = self._client_channels.get((client.id, channel_id))
        if target is not None and self._on_client_message is not None:
            self._on_client_message(client.id, target[0], target[1], data)

    # -- inspection and shutdown -------------------------------------------------------------------------
    def channels(self) -> list[tuple[str, str, int]]:
        """(topic, type name, channel id) of every channel advertised so far."""
        with self._lock:
            return [(c.topic, c.type_name, cid) for cid, c in self._by_id.items()]

    def stats(self) -> dict[str, Any]:
        """Counters per topic and per client (a snapshot, JSON-ready)."""
        with self._lock:
            topics: dict[str, dict[str, int]] = {}
            for (topic, _), chan in list(self._channels.items()):
                t = topics.setdefault(topic, {"received": 0, "sent": 0, "dropped": 0, "decode_errors": 0})
                for k, v in asdict(chan.stats).items():
                    t[k] += v
            for (topic, _), pending in self._pending.items():
                t = topics.setdefault(topic, {"received": 0, "sent": 0, "dropped": 0, "decode_errors": 0})
                t["dropped"] += pending.dropped
            clients = {str(cid): {"sent": dict(c.sent), "dropped": dict(c.dropped),
                                  "latched_resent": c.latched_resent, "connected": c.connected}
                       for cid, c in self._clients.items()}
        return {"topics": topics, "clients": clients, "queued": len(self._queue)}

    def stop(self) -> None:
        """Stop the sender thread and the server (clients are disconnected). Idempotent."""
        self._stopping = True
        self._wake.set()
        self._thread.join(2.0)
        self._server.stop()


class _Listener(ServerListener):
    """The SDK's ServerListener protocol (its other callbacks keep their no-op defaults), forwarding to
    :class:`SdkServer`."""

    def __init__(self, server: SdkServer) -> None:
        self._server = server

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self._server._subscribed(client, channel)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        self._server._unsubscribed(client, channel)

    def on_client_advertise(self, client: Client, channel: ClientChannel) -> None:
        self._server._client_advertised(client, channel)

    def on_client_unadvertise(self, client: Client, client_channel_id: int) -> None:
        self._server._client_channels.pop((client.id, client_channel_id), None)

    def on_message_data(self, client: Client, client_channel_id: int, data: bytes) -> None:
        self._server._client_data(client, client_channel_id, data)
