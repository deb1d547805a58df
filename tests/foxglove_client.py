"""A small Foxglove WebSocket protocol client for tests and bench/viz.py, written from the protocol description
(text frames are JSON ops; a server data frame is opcode 0x01, u32 LE subscription id, u64 LE log time, payload;
a client data frame is opcode 0x01, u32 LE client channel id, payload)."""

from __future__ import annotations

import json
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from palpa.viz import SUBPROTOCOL


@dataclass
class Received:
    topic: str
    log_time: int
    data: dict[str, Any]
    at: float
    """time.monotonic() when it arrived."""


@dataclass
class FoxgloveClient:
    """Connects, records what the server advertises and every data message of the subscribed channels."""

    url: str
    ws: ClientConnection | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Advertised channels by id (topic, encoding, schemaName, schema, schemaEncoding)."""
    messages: list[Received] = field(default_factory=list)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    _subs: dict[int, int] = field(default_factory=dict)  # subscription id -> channel id
    _next_sub: int = 1

    def open(self, timeout: float = 5.0) -> FoxgloveClient:
        self.ws = connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=timeout)  # type: ignore[list-item]
        self.ws.__enter__()  # websockets wants the connection used as a context manager; close() ends it
        return self

    def close_abruptly(self) -> None:
        """Drop the TCP connection without a WebSocket close handshake."""
        assert self.ws is not None
        self.ws.socket.close()

    def pump(self, seconds: float) -> None:
        """Read and record frames for ``seconds`` (or until the connection ends)."""
        assert self.ws is not None
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                return
            except ConnectionClosed:
                return
            self._handle(frame)

    def pump_until(self, done: Any, timeout: float, what: str) -> None:
        """Read until ``done()`` is true; fails naming ``what`` after ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}; channels "
                                     f"{sorted(c['topic'] for c in self.channels.values())}")
            self.pump(0.05)

    def _handle(self, frame: str | bytes) -> None:
        if isinstance(frame, str):
            msg = json.loads(frame)
            op = msg.get("op")
            if op == "serverInfo":
                self.server_info = msg
            elif op == "advertise":
                for ch in msg["channels"]:
                    self.channels[ch["id"]] = ch
            elif op == "unadvertise":
                for cid in msg["channelIds"]:
                    self.channels.pop(cid, None)
            elif op == "status":
                self.statuses.append(msg)
            return
        if frame[0] == 0x01:
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            channel = self.channels.get(self._subs.get(sub_id, -1), {})
            self.messages.append(Received(channel.get("topic", "?"), log_time, json.loads(frame[13:]),
                                          time.monotonic()))

    def channel(self, topic: str) -> dict[str, Any] | None:
        return next((c for c in self.channels.values() if c["topic"] == topic), None)

    def subscribe(self, *topics: str) -> None:
        """Subscribe to advertised topics (all of them with no argument)."""
        assert self.ws is not None
        subs = []
        for cid, ch in self.channels.items():
            if (not topics or ch["topic"] in topics) and cid not in self._subs.values():
                self._subs[self._next_sub] = cid
                subs.append({"id": self._next_sub, "channelId": cid})
                self._next_sub += 1
        if subs:
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def advertise(self, channel_id: int, topic: str, schema_name: str) -> None:
        assert self.ws is not None
        self.ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": channel_id, "topic": topic, "encoding": "json", "schemaName": schema_name}]}))

    def publish(self, channel_id: int, message: dict[str, Any]) -> None:
        assert self.ws is not None
        self.ws.send(b"\x01" + struct.pack("<I", channel_id) + json.dumps(message).encode())

    def of(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]

    def close(self) -> None:
        """The close handshake, reading meanwhile: websockets stops reading the socket while the receive queue of
        a client that stopped reading is full, so the server's close frame would sit behind unread data until the
        close timeout (10 s)."""
        if self.ws is None:
            return
        closer = threading.Thread(target=self.ws.close, name="foxglove-client-close", daemon=True)
        closer.start()
        end = time.monotonic() + 20.0  # websockets' own close_timeout (10 s) ends it sooner
        while closer.is_alive():
            if time.monotonic() > end:
                raise AssertionError("the Foxglove client's close handshake did not end within 20 s")
            self.pump(0.05)
            closer.join(0.01)
