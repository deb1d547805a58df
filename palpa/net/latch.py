"""The bus's last-value cache: what it accepts (a SET must be a well-formed message of a latched topic) and how much
it holds (bounded by entries and by bytes), so that no client can grow the bus without limit or have garbage
pushed to every later subscriber. The bus (palpa.net.bus) serves it on its ROUTER socket; see docs/wire.md.
"""

from __future__ import annotations

import msgspec

from palpa.errors import DecodeError, RegistryError
from palpa.message import lookup
from palpa.net.direct import CLIENT_KEYS_TOPIC, DIRECTORY_PREFIX
from palpa.net.wire import MAX_TOPIC_BYTES, decode_header

__all__ = ["DEFAULT_LATCH_MAX_BYTES", "DEFAULT_LATCH_MAX_ENTRIES", "LatchCache"]

DEFAULT_LATCH_MAX_BYTES = 64 * 2**20
DEFAULT_LATCH_MAX_ENTRIES = 4096
_ENDPOINT_MAX = 1024
_any_decoder = msgspec.msgpack.Decoder()


class LatchCache:
    """Topic -> last value (header, payload, blobs...). Not thread-safe: the bus holds a lock around it."""

    def __init__(self, latched_topics: frozenset[bytes], max_bytes: int = DEFAULT_LATCH_MAX_BYTES,
                 max_entries: int = DEFAULT_LATCH_MAX_ENTRIES) -> None:
        self._graph_latched = latched_topics
        self.max_bytes = max_bytes
        self.max_entries = max_entries
        self.values: dict[bytes, list[bytes]] = {}
        self._sizes: dict[bytes, int] = {}
        self.bytes = 0
        self.refused = 0
        """SETs refused (malformed, not a latched topic, or over a bound)."""

    def check(self, topic: bytes, value: list[bytes]) -> str | None:
        """Why ``SET topic *value`` must be refused, or None when it is a well-formed value of a latched topic."""
        if len(value) < 2:
            return f"SET needs topic, header and payload frames; got {len(value)} after the topic"
        if not topic or len(topic) > MAX_TOPIC_BYTES:
            return f"topic of {len(topic)} bytes (1..{MAX_TOPIC_BYTES})"
        try:
            topic.decode()
        except UnicodeDecodeError:
            return "topic is not UTF-8"
        header, payload = value[0], value[1]
        if topic.startswith(CLIENT_KEYS_TOPIC.rpartition(b"/")[0] + b"/"):
            return "topics under _palpa/curve/ are written by the bus only"
        if topic.startswith(DIRECTORY_PREFIX):  # a direct publisher's announcement (palpa.net.direct)
            if len(value) != 2 or header or len(payload) > _ENDPOINT_MAX or b"\0" not in topic:
                return "malformed direct-topic announcement"
            return None
        try:
            h = decode_header(header)
        except DecodeError as exc:
            return str(exc)
        if not (h.latched or topic in self._graph_latched):
            # plain text, as every ERR reason (docs/wire.md): not Python's b'...' spelling of the bytes
            return f"topic '{topic[:80].decode(errors='replace')}' is not latched (header without latched: true, " \
                   "not in bus.latched)"
        try:
            cls = lookup(h.type)
        except RegistryError:
            cls = None
        try:
            if cls is not None:
                msgspec.msgpack.decode(payload, type=cls)
            elif not isinstance(_any_decoder.decode(payload), dict):
                return f"{h.type}: payload is not a msgpack map"
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            return f"{h.type}: {exc}"
        return None

    def put(self, topic: bytes, value: list[bytes]) -> str | None:
        """Store a checked value; returns why not when a bound would be exceeded (the old value is kept)."""
        size = len(topic) + sum(len(f) for f in value)
        old = self._sizes.get(topic)
        if old is None and len(self.values) >= self.max_entries:
            return f"latch cache full ({self.max_entries} topics)"
        if self.bytes - (old or 0) + size > self.max_bytes:
            return f"latch cache full ({self.bytes} of {self.max_bytes} bytes; this value is {size})"
        self.values[topic] = value
        self._sizes[topic] = size
        self.bytes += size - (old or 0)
        return None

    def matching(self, prefix: bytes) -> list[tuple[bytes, list[bytes]]]:
        """Every cached (topic, value) whose topic starts with ``prefix``."""
        return [(t, v) for t, v in self.values.items() if t.startswith(prefix)]
