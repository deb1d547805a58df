r"""The bus's last-value cache and its table of watchers: what the cache accepts (a SET must be a well-formed message
of a latched topic) and how much both hold, so that no client can grow the bus without limit, have garbage pushed to
every later subscriber, or lock the graph's own nodes out. The bus (palpa.net.bus) serves them on its ROUTER socket; see
docs/wire.md and docs/limits.md.

Both are :class:`OwnedTable`\ s: every entry belongs to the client (ROUTER identity) that set it and to that
client's peer (the process behind it on an ipc bus, its address on a tcp one), and when a bound is reached the least
recently set entry of the greediest client of the peer holding the most is evicted. A client flooding the bus thus
only ever evicts its own peer's entries while that peer holds more than anyone else, however many connections it
spreads the flood over, and a node started later always gets room.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterator
from typing import Generic, TypeVar

import msgspec

from palpa.errors import DecodeError, RegistryError
from palpa.message import lookup
from palpa.net.direct import CLIENT_KEYS_TOPIC, DIRECTORY_PREFIX
from palpa.net.wire import DECODE_ERRORS, MAX_TOPIC_BYTES, decode_any, decode_header

__all__ = ["BUS_OWNER", "DEFAULT_LATCH_MAX_BYTES", "DEFAULT_LATCH_MAX_ENTRIES", "MAX_CLIENTS_PER_PEER",
           "MAX_WATCHES", "MAX_WATCH_BYTES", "LatchCache", "OwnedTable", "Watchers"]

DEFAULT_LATCH_MAX_BYTES = 64 * 2**20
DEFAULT_LATCH_MAX_ENTRIES = 4096
MAX_WATCHES = 16_384
"""(prefix, client) pairs the bus pushes later SETs to (one per latched GET)."""
MAX_WATCH_BYTES = 4 * 2**20
"""Bytes of watched prefixes, all clients together."""
MAX_CLIENTS_PER_PEER = 256
"""Clients (connections) through which one peer (a process on an ipc bus, an address on a tcp one) may hold cache
entries, and, apart, watches."""
BUS_OWNER = b""
"""The owner of what the bus itself caches (captured graph-latched topics, the client keys): never evicted."""
_ENDPOINT_MAX = 1024

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class OwnedTable(Generic[K, V]):
    """Key -> value, each entry owned by one client of one peer, bounded by ``max_entries`` and ``max_bytes`` (of
    the sizes given to :meth:`put`). Making room evicts from the peer holding the most entries (for the entry bound)
    or bytes (for the byte bound), within it from its client holding the most, that client's least recently set
    entry; entries of :data:`BUS_OWNER` are never evicted. A peer (a process, a host: :func:`palpa.net.bus.peer_of`)
    holds entries through at most ``max_clients_per_peer`` clients: spreading a flood over many connections buys it
    nothing."""

    def __init__(self, max_entries: int, max_bytes: int, max_clients_per_peer: int = MAX_CLIENTS_PER_PEER) -> None:
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self.max_clients_per_peer = max_clients_per_peer
        self.values: dict[K, V] = {}
        self._meta: dict[K, tuple[bytes, int]] = {}  # key -> (owner, size)
        self._owned: dict[bytes, dict[K, None]] = {}  # owner -> its keys, least recently set first
        self._owner_bytes: dict[bytes, int] = {}
        self._peer_of: dict[bytes, bytes] = {}  # owner (holding entries) -> its peer
        self._clients: dict[bytes, dict[bytes, None]] = {}  # peer -> its owners holding entries
        self._peer_entries: dict[bytes, int] = {}
        self._peer_bytes: dict[bytes, int] = {}
        self.bytes = 0
        self.evicted = 0
        """Entries evicted to make room so far."""
        self.refused_clients = 0
        """Puts refused because the client's peer already held entries through ``max_clients_per_peer`` others."""

    def __len__(self) -> int:
        return len(self.values)

    def __contains__(self, key: object) -> bool:
        return key in self.values

    def __iter__(self) -> Iterator[K]:
        return iter(self.values)

    def put(self, key: K, value: V, size: int, owner: bytes,
            peer: bytes | None = None) -> tuple[str | None, list[tuple[bytes, K]]]:
        """Store ``value`` (replacing ``key``'s old value, whoever set it) for ``owner``, a client of ``peer``
        (None: a peer of its own), evicting what must go; returns (why it cannot be stored, or None; the evicted
        (owner, key) pairs). A refusal changes nothing."""
        peer = owner if peer is None else peer
        old = self._meta.get(key)
        # what may not be evicted (the bus's own entries, and this key's old value, which is replaced) must leave
        # room for the new value, or nothing changes
        kept = self._owned.get(BUS_OWNER, {})
        kept_entries = len(kept) - (key in kept)
        kept_bytes = self._owner_bytes.get(BUS_OWNER, 0) - (old[1] if old is not None and key in kept else 0)
        if kept_entries + 1 > self.max_entries or kept_bytes + size > self.max_bytes:
            return (f"full: a value of {size} bytes does not fit in {self.max_bytes} bytes and "
                    f"{self.max_entries} entries"), []
        clients = self._clients.get(peer, {})
        if owner != BUS_OWNER and owner not in clients and len(clients) >= self.max_clients_per_peer:
            self.refused_clients += 1
            return (f"peer {peer[:80].decode(errors='replace')} already uses "
                    f"{len(clients)} connections here (at most {self.max_clients_per_peer} per peer)"), []
        if old is not None:
            self.pop(key)
        evicted: list[tuple[bytes, K]] = []
        while len(self.values) >= self.max_entries or self.bytes + size > self.max_bytes:
            victim = self._greediest(by_bytes=len(self.values) < self.max_entries)
            evicted.append((self._meta[victim][0], victim))
            self.pop(victim)
            self.evicted += 1
        self.values[key] = value
        self._meta[key] = (owner, size)
        self._owned.setdefault(owner, {})[key] = None
        self._owner_bytes[owner] = self._owner_bytes.get(owner, 0) + size
        self._peer_of[owner] = peer
        self._clients.setdefault(peer, {})[owner] = None
        self._peer_entries[peer] = self._peer_entries.get(peer, 0) + 1
        self._peer_bytes[peer] = self._peer_bytes.get(peer, 0) + size
        self.bytes += size
        return None, evicted

    def _greediest(self, by_bytes: bool) -> K:
        """The least recently set key of the client holding the most entries (or bytes) within the peer (the bus
        aside) holding the most."""
        peers = [p for p in self._clients if p != BUS_OWNER]
        if by_bytes:
            peer = max(peers, key=self._peer_bytes.__getitem__)
            worst = max(self._clients[peer], key=self._owner_bytes.__getitem__)
        else:
            peer = max(peers, key=self._peer_entries.__getitem__)
            worst = max(self._clients[peer], key=lambda o: len(self._owned[o]))
        return next(iter(self._owned[worst]))

    def pop(self, key: K) -> V | None:
        """Remove ``key``; its value, or None when absent."""
        meta = self._meta.pop(key, None)
        if meta is None:
            return None
        owner, size = meta
        peer = self._peer_of[owner]
        keys = self._owned[owner]
        del keys[key]
        self._owner_bytes[owner] -= size
        self._peer_entries[peer] -= 1
        self._peer_bytes[peer] -= size
        if not keys:
            del self._owned[owner]
            del self._owner_bytes[owner]
            del self._peer_of[owner]
            clients = self._clients[peer]
            del clients[owner]
            if not clients:
                del self._clients[peer]
                del self._peer_entries[peer]
                del self._peer_bytes[peer]
        self.bytes -= size
        return self.values.pop(key)


class Watchers:
    """Who asked to be told of later SETs under which prefix (a latched GET), indexed by prefix so that a SET
    costs one lookup per prefix of its topic, however many watchers there are. Bounded by :data:`MAX_WATCHES` and
    :data:`MAX_WATCH_BYTES` (an :class:`OwnedTable`: the greediest client's oldest watch goes first)."""

    def __init__(self, max_watches: int = MAX_WATCHES, max_bytes: int = MAX_WATCH_BYTES) -> None:
        self._table: OwnedTable[tuple[bytes, bytes], None] = OwnedTable(max_watches, max_bytes)
        self._by_prefix: dict[bytes, set[bytes]] = {}

    def __len__(self) -> int:
        return len(self._table)

    @property
    def evicted(self) -> int:
        return self._table.evicted

    def add(self, prefix: bytes, ident: bytes, peer: bytes | None = None) -> str | None:
        """Watch ``prefix`` for ``ident``, a client of ``peer`` (evicting the greediest peer's greediest client's
        oldest watch when full); why not (one prefix over the byte bound, too many clients of that peer), or
        None."""
        why, evicted = self._table.put((prefix, ident), None, len(prefix) + len(ident), ident, peer)
        for _owner, (p, i) in evicted:
            self._unindex(p, i)
        if why is None:
            self._by_prefix.setdefault(prefix, set()).add(ident)
        return why

    def discard(self, prefix: bytes, ident: bytes) -> None:
        self._table.pop((prefix, ident))
        self._unindex(prefix, ident)

    def _unindex(self, prefix: bytes, ident: bytes) -> None:
        idents = self._by_prefix.get(prefix)
        if idents is not None:
            idents.discard(ident)
            if not idents:
                del self._by_prefix[prefix]

    def matching(self, topic: bytes) -> list[tuple[bytes, bytes]]:
        """(prefix, ident) of every watch whose prefix ``topic`` starts with."""
        by_prefix = self._by_prefix
        out: list[tuple[bytes, bytes]] = []
        for end in range(len(topic) + 1):
            idents = by_prefix.get(topic[:end])
            if idents:
                out.extend((topic[:end], i) for i in idents)
        return out


class LatchCache:
    """Topic -> last value (header, payload, blobs...), an :class:`OwnedTable` by client. Not thread-safe: the bus
    holds a lock around it."""

    def __init__(self, latched_topics: frozenset[bytes], max_bytes: int = DEFAULT_LATCH_MAX_BYTES,
                 max_entries: int = DEFAULT_LATCH_MAX_ENTRIES) -> None:
        self._graph_latched = latched_topics
        self.table: OwnedTable[bytes, list[bytes]] = OwnedTable(max_entries, max_bytes)
        self.values = self.table.values
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
        try:  # nesting first, for every type: a typed decode would skip a deep unknown field recursively
            if not isinstance(decode_any(payload), dict):
                return f"{h.type}: payload is not a msgpack map"
            if cls is not None:
                msgspec.msgpack.decode(payload, type=cls)
        except (DecodeError, *DECODE_ERRORS) as exc:
            return f"{h.type}: {exc}"
        return None

    def put(self, topic: bytes, value: list[bytes], owner: bytes = BUS_OWNER,
            peer: bytes | None = None) -> tuple[str | None, list[bytes]]:
        """Store a checked value set by ``owner``, a client of ``peer``; returns (why not, the old value kept; the
        topics evicted)."""
        why, evicted = self.table.put(topic, value, len(topic) + sum(len(f) for f in value), owner, peer)
        return (None if why is None else f"latch cache {why}"), [k for _o, k in evicted]

    def matching(self, prefix: bytes) -> list[tuple[bytes, list[bytes]]]:
        """Every cached (topic, value) whose topic starts with ``prefix``."""
        return [(t, v) for t, v in self.values.items() if t.startswith(prefix)]
