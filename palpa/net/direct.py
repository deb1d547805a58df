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
ZeroMQ PUB socket: a subscriber counts as ready only once the direct publishers known to it have its subscriptions
(palpa.net.reach); one that appears later is waited for by the lockstep clock only (palpa.timing.lockstep), and
:meth:`palpa.Publisher.wait_for_subscribers` tells when someone listens.

On a CURVE bus (across hosts) the direct socket is a CURVE server too: it binds on this host's address on the route
to the bus (or ``PALPA_DIRECT_HOST``), with a key pair made for it, and announces its public key beside the
endpoint (``endpoint\0key``), so a subscriber learns whom to trust through the bus's authenticated directory. It
lets in exactly the clients the bus lets in: the bus publishes its authorised client keys in its cache
(:data:`CLIENT_KEYS_TOPIC`, refreshed on reload), and the socket announces itself only once it has them, so no
subscriber meets it before it knows whom to accept (libzmq never retries a refused handshake).
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import socket
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import zmq

from palpa import env as palpa_env
from palpa.lograte import LogThrottle
from palpa.net.address import BusAddress, is_loopback_host
from palpa.net.wire import Header, encode_header

__all__ = [
    "ATTACH_MARK", "CLIENT_KEYS_TOPIC", "DIRECTORY_PREFIX", "JOIN_PROBE_PREFIX", "REACH_PREFIX", "DirectSocket", "SubscriberSet",
    "bind_candidates",
    "directory_entry", "directory_key", "directory_value", "follow_directory",
]

DIRECTORY_PREFIX = b"_palpa/direct/"
JOIN_PROBE_PREFIX = b"_palpa/join/"
"""Readiness probes: a node subscribes ``_palpa/join/<node>/<id>`` after its setup (palpa.node.presence)."""
JOIN_PROBE_SUB = b"\x01" + JOIN_PROBE_PREFIX
REACH_PREFIX = b"_palpa/reach/"
"""Direct readiness probes: a subscriber subscribes ``_palpa/reach/<token>/<n>`` after connecting to a direct
publisher, and the publisher's direct socket answers it with one message whose payload is its endpoint (palpa.net.reach)."""
_REACH_SUB = b"\x01" + REACH_PREFIX
CLIENT_KEYS_TOPIC = b"_palpa/curve/clients"
"""The cache key under which a CURVE bus publishes its authorised client keys (Z85, one a line); only the bus
writes under ``_palpa/curve/``."""
log = logging.getLogger("palpa.net.transport")
_IPC_MAX = 100  # sun_path holds 107 bytes
_counter = itertools.count()


def directory_key(topic: bytes, endpoint: str) -> bytes:
    """The cache key announcing that ``topic`` is published at ``endpoint`` (one key per publisher)."""
    return DIRECTORY_PREFIX + topic + b"\0" + endpoint.encode()


def directory_value(endpoint: str, server_key: bytes | None) -> bytes:
    """An announcement's value: the endpoint, and the CURVE server's public key after a NUL when encrypted."""
    return endpoint.encode() + (b"\0" + server_key if server_key else b"")


def directory_entry(key: bytes, payload: bytes) -> tuple[str, bool, bytes | None] | None:
    """``(endpoint, alive, CURVE server key or None)`` from one cached announcement, None when ``key`` is not a
    directory entry."""
    if not key.startswith(DIRECTORY_PREFIX):
        return None
    _, sep, endpoint = key.rpartition(b"\0")
    if not sep or not endpoint:
        return None
    _, sep, server_key = payload.partition(b"\0")
    return endpoint.decode(errors="replace"), bool(payload), server_key if sep and server_key else None


def follow_directory(sub: zmq.Socket[bytes], peers: set[str], key: bytes, payload: bytes,
                     bus_server_key: bytes | None) -> str | None:
    """Connect ``sub`` to a direct publisher the cache told about (once per endpoint, recorded in ``peers``), with
    its CURVE key when the bus is encrypted (``bus_server_key``: the key ``sub`` uses for the bus, put back after).
    A withdrawn one is not disconnected: its last messages may still be on their way (a disconnect would drop
    them); ZeroMQ keeps retrying a dead endpoint at most every few seconds, and a publisher that comes back there
    is received once, not twice. The endpoint when a new connection was made, else None."""
    entry = directory_entry(key, payload)
    if entry is None:
        return None
    endpoint, alive, server_key = entry
    if not alive or endpoint in peers:
        return None
    if (bus_server_key is None) != (server_key is None):
        log.warning("cannot connect to direct publisher %s: it is %s and this node's bus is %s", endpoint,
                    *(("encrypted", "not") if server_key else ("not encrypted", "encrypted")))
        return None
    try:
        if server_key is not None:  # libzmq copies the options at connect: later reconnects keep this key
            sub.curve_serverkey = server_key
        sub.connect(endpoint)
    except zmq.ZMQError as exc:
        log.warning("cannot connect to direct publisher %s: %s", endpoint, exc)
        return None
    finally:
        if server_key is not None and bus_server_key is not None:
            sub.curve_serverkey = bus_server_key
    peers.add(endpoint)
    return endpoint


def own_address_towards(host: str) -> str:
    """This machine's address on the route to ``host`` (``PALPA_DIRECT_HOST`` when set): where a peer that reaches
    the bus can reach us too. A UDP connect sends nothing; it only asks the kernel for the route."""
    override = palpa_env.get(palpa_env.DIRECT_HOST)
    if override:
        return override
    try:
        family, _, _, _, sockaddr = socket.getaddrinfo(host.strip("[]"), 9, proto=socket.IPPROTO_UDP)[0]
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect(sockaddr)
            own = str(probe.getsockname()[0])
    except OSError:
        return ""
    return f"[{own}]" if ":" in own else own


def bind_candidates(address: BusAddress, curve: bool = False) -> list[str]:
    """Where a node may bind its direct socket, best first. A bus on another host is reached over tcp with CURVE
    only: then this host's address on the route to it (:func:`own_address_towards`); without CURVE, nothing
    (a plaintext socket beyond loopback would let anyone on the network read the topic)."""
    tag = f"d{os.getpid()}-{next(_counter)}"
    if address.pub.startswith("ipc://"):
        path = address.pub[len("ipc://") :]
        base = path[: -len(".pub")] if path.endswith(".pub") else path
        out = [f"{base}.{tag}", os.path.join(tempfile.gettempdir(), f"palpa-{tag}")]
        return [f"ipc://{p}" for p in out if len(p) <= _IPC_MAX]
    if address.pub.startswith("tcp://"):
        host = address.pub[len("tcp://") :].rpartition(":")[0]
        if is_loopback_host(host):
            return [f"tcp://{'127.0.0.1' if host == 'localhost' else host}:*"]
        own = own_address_towards(host) if curve else ""
        if own:
            return [f"tcp://{own}:*"]
    return []


ATTACH_MARK = b"_palpa/attach"
"""The topic the bus's proxy subscribes to for itself and nobody publishes (palpa.net.bus): a publisher attaching
to the proxy always hears this one subscription, so it knows at once that it has heard them all."""


_COVERS_MAX = 4096


class SubscriberSet:
    """The subscriptions an XPUB socket has heard (ZeroMQ sends each prefix once, ``\\x01prefix``, and
    ``\\x00prefix`` when its last subscriber leaves), so a publisher can tell whether anyone listens."""

    def __init__(self) -> None:
        self.prefixes: set[bytes] = set()
        self._covers: dict[bytes, bool] = {}  # topic -> covers(topic), until the prefixes change
        self.joined: dict[str, None] = {}
        """The readiness probes (``_palpa/join/<node>/<pid>.<incarnation>``, palpa.node.presence; kept without the prefix)
        this socket has heard subscribed:
        it has every subscription those nodes made before they were ready (one connection delivers in order). In
        the order heard (a dict: an ordered set)."""

    def note(self, message: bytes) -> None:
        """Record one subscription message read from the XPUB socket."""
        if message[1:] == ATTACH_MARK:
            return  # the proxy's own: nobody listens to it
        self._covers.clear()
        if message[:1] == b"\x01":
            self.prefixes.add(message[1:])
            if message.startswith(JOIN_PROBE_SUB):
                self.joined[message[len(JOIN_PROBE_SUB):].decode(errors="replace")] = None
        elif message[:1] == b"\x00":
            self.prefixes.discard(message[1:])

    def covers(self, topic: bytes) -> bool:
        """True when some subscription's prefix matches ``topic`` (asked at every message a composition sends
        out: the answer is kept per topic until a subscription comes or goes)."""
        known = self._covers.get(topic)
        if known is None:
            if len(self._covers) >= _COVERS_MAX:
                self._covers.clear()
            known = self._covers[topic] = any(topic.startswith(p) for p in self.prefixes)
        return known


class _AllowedKeys:
    """The client keys a direct CURVE socket lets in: the bus's authorised set, as last published (pyzmq's ZAP
    credentials provider; the ZAP thread reads the set, the node's thread replaces it whole)."""

    def __init__(self) -> None:
        self.keys: frozenset[bytes] | None = None
        self.refused = 0
        self._throttle = LogThrottle(log)

    def callback(self, domain: str, z85_key: bytes) -> bool:
        if self.keys is not None and z85_key in self.keys:
            return True
        self.refused += 1
        self._throttle.event("refused", logging.WARNING, "direct topic socket: refused a subscriber with key %s "
                             "(not authorised on the bus; %d refusals so far)", z85_key.decode(errors="replace"),
                             self.refused)
        return False


class DirectSocket:
    """The XPUB a node's direct topics leave from, what it has heard subscribed, and its directory entries; on a
    CURVE bus also its key pair, its own context and ZAP thread, and the keys it accepts."""

    def __init__(self, sock: zmq.Socket[bytes], endpoint: str, curve: _Curve | None = None) -> None:
        self.sock = sock
        self.endpoint = endpoint
        self.topics: list[bytes] = []
        self.listeners = SubscriberSet()
        self._curve = curve
        self._pending: list[bytes] = []

    @classmethod
    def bind(
        cls, ctx: zmq.Context[zmq.Socket[bytes]], address: BusAddress, sndhwm: int, curve: bool = False
    ) -> DirectSocket | str:
        """Bind next to the bus (see :func:`bind_candidates`); the reason as a string when nothing would bind.
        With ``curve`` the socket is a CURVE server with a fresh key pair in a context of its own (its ZAP
        handler must not meet another node's in a shared context)."""
        candidates = bind_candidates(address, curve)
        why = f"the bus {address.pub} is neither ipc nor loopback tcp" + \
            ("" if curve else " (beyond loopback, direct topics need CURVE)")
        if not candidates:
            return why
        sec: _Curve | None = _Curve() if curve else None
        sock = (sec.ctx if sec is not None else ctx).socket(zmq.XPUB)
        sock.sndhwm = sndhwm
        if sec is not None:
            sock.curve_secretkey = sec.secret
            sock.curve_publickey = sec.public
            sock.curve_server = True
        for endpoint in candidates:
            try:
                sock.bind(endpoint)
            except zmq.ZMQError as exc:
                why = f"cannot bind {endpoint}: {exc}"
                continue
            return cls(sock, str(sock.getsockopt_string(zmq.LAST_ENDPOINT)), sec)
        sock.close(0)
        if sec is not None:
            sec.close()
        return why

    @property
    def server_key(self) -> bytes | None:
        """The CURVE public key subscribers must expect (None in plaintext)."""
        return self._curve.public if self._curve is not None else None

    def accepts(self, z85_key: bytes) -> bool:
        """Whether a subscriber with this CURVE public key would be let in now (plaintext: anyone who can reach
        the socket, which is then loopback or ipc only)."""
        return self._curve is None or z85_key in (self._curve.allowed.keys or ())

    def carries(self, topic: bytes) -> bool:
        """Whether ``topic`` leaves from this socket (announced, or waiting for the client keys to be)."""
        return topic in self.topics or topic in self._pending

    @property
    def ready(self) -> bool:
        """Whether announcing is safe: always in plaintext; with CURVE once the bus's client keys are known."""
        return self._curve is None or self._curve.allowed.keys is not None

    def allow(self, to_cache: Callable[[list[bytes]], None], keys_payload: bytes) -> None:
        """The bus's authorised client keys (one Z85 key a line) arrived or changed: accept exactly those, and
        make the announcements that waited for them."""
        if self._curve is None:
            return
        self._curve.allowed.keys = frozenset(k for k in keys_payload.split(b"\n") if k)
        pending, self._pending = self._pending, []
        for topic in pending:
            self.announce(to_cache, topic)

    def announce(self, to_cache: Callable[[list[bytes]], None], topic: bytes) -> None:
        """Tell the bus's directory (through ``to_cache``, the transport's non-blocking send to the cache) that ``topic`` is published here (with CURVE, as
        soon as the client keys are known)."""
        if topic in self.topics:
            return
        if not self.ready:
            if topic not in self._pending:
                self._pending.append(topic)
            return
        self.topics.append(topic)
        to_cache([b"SET", directory_key(topic, self.endpoint), b"", directory_value(self.endpoint, self.server_key)])

    def drain(self) -> None:
        """Read the subscriptions that arrived (:class:`SubscriberSet`) and answer each direct readiness probe
        among them (:data:`REACH_PREFIX`) with the endpoint: its subscriber's earlier subscriptions came on the
        same connection before it, so they are in this socket's filter now, and the answer travels the path a
        message would. Subscriptions only: nothing per message."""
        listeners = self.listeners
        while True:
            try:
                message = self.sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            listeners.note(message)
            if message.startswith(_REACH_SUB):
                header = encode_header(Header(type="", seq=0, stamp=time.time_ns(), node=self.endpoint))
                with contextlib.suppress(zmq.Again):  # a full queue: unanswered, its subscriber's wait is bounded
                    self.sock.send_multipart([message[1:], header, self.endpoint.encode()], zmq.NOBLOCK)

    def close(self, to_cache: Callable[[list[bytes]], None], linger_ms: int) -> None:
        """Withdraw every announcement, close the socket and remove its ipc file."""
        for topic in self.topics:
            to_cache([b"SET", directory_key(topic, self.endpoint), b"", b""])
        self.sock.close(linger_ms)
        if self._curve is not None:
            self._curve.close()
        if self.endpoint.startswith("ipc://"):
            Path(self.endpoint[len("ipc://") :]).unlink(missing_ok=True)


class _Curve:
    """A direct socket's CURVE side: a key pair of its own, a context of its own, and the ZAP thread deciding
    whom to let in."""

    def __init__(self) -> None:
        # here, not at the top: it imports asyncio and more, which only a CURVE socket needs
        from zmq.auth.thread import ThreadAuthenticator

        self.public, self.secret = zmq.curve_keypair()
        self.ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        self.allowed = _AllowedKeys()
        self.auth = ThreadAuthenticator(self.ctx, log=logging.getLogger("palpa.net.direct.zap"))
        self.auth.start()
        self.auth.configure_curve_callback(domain="*", credentials_provider=self.allowed)

    def close(self) -> None:
        self.auth.stop()
        self.ctx.term()
