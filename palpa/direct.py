"""Direct topics: a publisher sends straight to its subscribers' sockets, and the bus is only the directory.

Every message through the proxy crosses two ZeroMQ hops, and each hop costs two thread wake-ups (the sender's I/O
thread, then the receiver's). A topic published *direct* skips the proxy: the publishing node binds one more
socket (an XPUB next to the bus's own ipc files, or on 127.0.0.1 for a loopback tcp bus) and announces
``topic -> endpoint`` in the bus's last-value cache under ``_palpa/direct/<topic>\\0<endpoint>``. A subscriber's
transport asks the cache for ``_palpa/direct/<prefix>`` whenever it subscribes, is told of announcements made
later, and connects its SUB socket to each endpoint it learns. A node that closes cleanly withdraws its
announcements (an empty endpoint), so later subscribers skip it; connected ones stay connected, since a
disconnect would drop what is still in flight. After a crash the stale entry only makes subscribers retry a dead
endpoint (every 2 s at most).

The price: a direct topic's messages do not pass the proxy, so the bus's own capture (launch ``bus.latched``)
does not see them (a publisher's ``latched=True`` still works), and a foreign client must follow the directory
(docs/wire.md). Messages published before a subscriber has connected are not delivered to it, as with any
ZeroMQ PUB socket; :meth:`palpa.Publisher.wait_for_subscribers` tells when someone listens.
"""

from __future__ import annotations

import itertools
import os
import tempfile
from pathlib import Path

import zmq

from palpa.address import BusAddress

__all__ = [
    "DIRECTORY_PREFIX", "DirectSocket", "SubscriberSet", "bind_candidates", "directory_entry", "directory_key",
]

DIRECTORY_PREFIX = b"_palpa/direct/"
_IPC_MAX = 100  # sun_path holds 107 bytes
_counter = itertools.count()


def directory_key(topic: bytes, endpoint: str) -> bytes:
    """The cache key announcing that ``topic`` is published at ``endpoint`` (one key per publisher)."""
    return DIRECTORY_PREFIX + topic + b"\0" + endpoint.encode()


def directory_entry(key: bytes, payload: bytes) -> tuple[str, bool] | None:
    """``(endpoint, alive)`` from one cached announcement, None when ``key`` is not a directory entry."""
    if not key.startswith(DIRECTORY_PREFIX):
        return None
    _, sep, endpoint = key.rpartition(b"\0")
    if not sep or not endpoint:
        return None
    return endpoint.decode(errors="replace"), bool(payload)


def bind_candidates(address: BusAddress) -> list[str]:
    """Where a node may bind its direct socket, best first; empty when the bus is not on this machine's loopback
    or ipc (a remote tcp bus: the node's own reachable address is unknown, so its topics stay on the bus)."""
    tag = f"d{os.getpid()}-{next(_counter)}"
    if address.pub.startswith("ipc://"):
        path = address.pub[len("ipc://") :]
        base = path[: -len(".pub")] if path.endswith(".pub") else path
        out = [f"{base}.{tag}", os.path.join(tempfile.gettempdir(), f"palpa-{tag}")]
        return [f"ipc://{p}" for p in out if len(p) <= _IPC_MAX]
    if address.pub.startswith("tcp://"):
        host = address.pub[len("tcp://") :].rpartition(":")[0]
        if host.startswith("127.") or host in ("localhost", "[::1]"):
            return [f"tcp://{'127.0.0.1' if host == 'localhost' else host}:*"]
    return []


class SubscriberSet:
    """The subscriptions an XPUB socket has heard (ZeroMQ sends each prefix once, ``\\x01prefix``, and
    ``\\x00prefix`` when its last subscriber leaves), so a publisher can tell whether anyone listens."""

    def __init__(self) -> None:
        self.prefixes: set[bytes] = set()

    def note(self, message: bytes) -> None:
        """Record one subscription message read from the XPUB socket."""
        if message[:1] == b"\x01":
            self.prefixes.add(message[1:])
        elif message[:1] == b"\x00":
            self.prefixes.discard(message[1:])

    def covers(self, topic: bytes) -> bool:
        """True when some subscription's prefix matches ``topic``."""
        return any(topic.startswith(p) for p in self.prefixes)


class DirectSocket:
    """The XPUB a node's direct topics leave from, what it has heard subscribed, and its directory entries."""

    def __init__(self, sock: zmq.Socket[bytes], endpoint: str) -> None:
        self.sock = sock
        self.endpoint = endpoint
        self.topics: list[bytes] = []
        self.listeners = SubscriberSet()

    @classmethod
    def bind(
        cls, ctx: zmq.Context[zmq.Socket[bytes]], address: BusAddress, sndhwm: int
    ) -> DirectSocket | str:
        """Bind next to the bus (see :func:`bind_candidates`); the reason as a string when nothing would bind."""
        candidates = bind_candidates(address)
        why = f"the bus {address.pub} is neither ipc nor loopback tcp"
        sock = ctx.socket(zmq.XPUB)
        sock.sndhwm = sndhwm
        for endpoint in candidates:
            try:
                sock.bind(endpoint)
            except zmq.ZMQError as exc:
                why = f"cannot bind {endpoint}: {exc}"
                continue
            return cls(sock, str(sock.getsockopt_string(zmq.LAST_ENDPOINT)))
        sock.close(0)
        return why

    def announce(self, latch: zmq.Socket[bytes], topic: bytes) -> None:
        """Tell the bus's directory (through the latch socket) that ``topic`` is published here."""
        if topic not in self.topics:
            self.topics.append(topic)
            latch.send_multipart([b"SET", directory_key(topic, self.endpoint), b"", self.endpoint.encode()])

    def close(self, latch: zmq.Socket[bytes], linger_ms: int) -> None:
        """Withdraw every announcement, close the socket and remove its ipc file."""
        for topic in self.topics:
            latch.send_multipart([b"SET", directory_key(topic, self.endpoint), b"", b""])
        self.sock.close(linger_ms)
        if self.endpoint.startswith("ipc://"):
            Path(self.endpoint[len("ipc://") :]).unlink(missing_ok=True)
