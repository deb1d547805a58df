"""The bus: one XSUB/XPUB proxy per graph plus a last-value cache for latched topics.

Publishers connect to the proxy's XSUB (``pub`` endpoint), subscribers to its XPUB (``sub``); the proxy itself runs
in libzmq (``zmq.proxy_steerable``), so no Python touches the hot path. Latched topics (a calibration, the scan
plan, the map) are kept by a small ROUTER service on the ``latch`` endpoint: a publisher that declares a topic
latched sends each message there as well (``SET``), and a subscriber asks for the last value when it subscribes
(``GET``), so a late joiner gets it without disturbing anyone else. Topics the *graph* declares latched (launch
``bus.latched``) are cached from a capture of the proxy stream, filtered by prefix inside libzmq.

Latch protocol (DEALER -> ROUTER), every frame bytes:
    SET topic header payload [blobs...]      no reply
    GET prefix                                -> VAL topic header payload [blobs...], one per cached topic that
                                                 starts with prefix (none when nothing matches); later SETs on
                                                 matching topics are pushed to the asker too, so a value set
                                                 while its subscription is still propagating is not lost
    UNWATCH prefix                            no reply: SETs on topics under prefix are no longer pushed to the
                                                 asker (what its GET of that prefix started; wire version 2)
    PING token                                -> PONG token: every reply to the asker's earlier requests came
                                                 before it (a node waits for its directory answers, palpa.net.reach)
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zmq
import zmq.auth

from palpa.errors import BusError
from palpa.lograte import LogThrottle
from palpa.net.address import BusAddress, is_loopback_host
from palpa.net.direct import ATTACH_MARK, CLIENT_KEYS_TOPIC, DIRECTORY_PREFIX
from palpa.net.keys import ClientKeys, load_secret_key
from palpa.net.latch import (
    BUS_OWNER,
    DEFAULT_LATCH_MAX_BYTES,
    DEFAULT_LATCH_MAX_ENTRIES,
    LatchCache,
    Watchers,
)
from palpa.net.wire import MAX_MSG_BYTES, MAX_TOPIC_BYTES

if TYPE_CHECKING:
    from zmq.auth.thread import ThreadAuthenticator

__all__ = ["Bus", "CurveServer", "is_loopback_endpoint", "peer_of"]

log = logging.getLogger("palpa.net.bus")

def peer_of(frame: zmq.Frame) -> bytes:
    """Who is behind a client of the bus, as the cache counts clients (palpa.net.latch): its CURVE key when it has
    one, and the peer address libzmq gives the message (``localhost:uid:gid:pid`` on ipc, the process; the IP
    address on tcp, the host; every local client is one peer on a loopback tcp bus). Empty parts when libzmq knows
    none (inproc)."""
    parts: list[str] = []
    for prop in ("User-Id", "Peer-Address"):
        try:
            parts.append(str(frame.get(prop)))
        except zmq.ZMQError:  # not given for this transport
            parts.append("")
    return "@".join(parts).encode()


def is_loopback_endpoint(endpoint: str) -> bool:
    """True for ipc/inproc endpoints and tcp endpoints on a loopback address: ``localhost`` itself or a
    literal loopback IP (127.0.0.0/8, ::1). Any other name (``localhost.example.com``, ``127.0.0.1.nip.io``)
    resolves through DNS and may be anything: not loopback."""
    if not endpoint.startswith("tcp://"):
        return True
    return is_loopback_host(endpoint[len("tcp://") :].rpartition(":")[0])


@dataclass(frozen=True)
class CurveServer:
    """CURVE settings of a bus: its secret key file and the folder of authorised client public keys."""

    secret_key_file: Path
    authorized_clients_dir: Path


class Bus:
    """A running proxy + last-value cache. ``start()`` binds and returns the resolved address; ``stop()`` ends it."""

    def __init__(
        self,
        address: BusAddress,
        *,
        latched_topics: Iterable[str] = (),
        hwm: int = 10_000,
        curve: CurveServer | None = None,
        max_msg_bytes: int = MAX_MSG_BYTES,
        latch_max_bytes: int = DEFAULT_LATCH_MAX_BYTES,
        latch_max_entries: int = DEFAULT_LATCH_MAX_ENTRIES,
    ) -> None:
        self._requested = address
        self._latched_topics = sorted(set(latched_topics))
        self._hwm = hwm
        self._curve = curve
        self._max_msg_bytes = max_msg_bytes
        self._ctx = zmq.Context()
        self._auth: ThreadAuthenticator | None = None
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._cache = LatchCache(frozenset(t.encode() for t in self._latched_topics), latch_max_bytes,
                                 latch_max_entries)
        self._cache_lock = threading.Lock()
        self._watchers = Watchers()
        self._throttle = LogThrottle(log)
        self.watch_refused = 0
        """Latched GETs whose watch was refused (prefix too long, or too long for the watcher table)."""
        self.internal_errors = 0
        """Latch requests whose handling raised (counted and logged; the cache thread goes on)."""
        self.address: BusAddress | None = None
        self.clients: ClientKeys | None = None
        """The authorised CURVE client keys (None without CURVE); ``clients.reload()`` rereads the folder."""

    def _secure(self, sock: zmq.Socket[bytes]) -> None:
        if self._curve is None:
            return
        public, secret = load_secret_key(self._curve.secret_key_file)
        sock.curve_secretkey = secret
        sock.curve_publickey = public
        sock.curve_server = True

    def _bind(self, sock: zmq.Socket[bytes], endpoint: str) -> str:
        if not is_loopback_endpoint(endpoint) and self._curve is None:
            raise BusError(
                f"refusing to bind {endpoint} without CURVE keys: binding beyond loopback needs "
                "--curve-secret and --curve-clients (see docs/wire.md)"
            )
        self._secure(sock)
        try:
            sock.bind(endpoint)
        except zmq.ZMQError as exc:
            raise BusError(f"cannot bind {endpoint}: {exc}") from None
        if endpoint.startswith("ipc://"):  # only this user may connect (connecting needs write permission)
            with contextlib.suppress(OSError):
                os.chmod(endpoint[len("ipc://") :], 0o600)
        return str(sock.getsockopt_string(zmq.LAST_ENDPOINT))

    def start(self) -> BusAddress:
        """Bind all three endpoints and start the proxy and cache threads."""
        if self._curve is not None:
            # here, not at the top: it imports asyncio and more, which only a CURVE bus needs
            from zmq.auth.thread import ThreadAuthenticator

            self.clients = ClientKeys(self._curve.authorized_clients_dir)
            self._auth = ThreadAuthenticator(self._ctx, log=logging.getLogger("palpa.net.bus.zap"))
            self._auth.start()
            self._auth.configure_curve_callback(domain="*", credentials_provider=self.clients)
        xsub = self._ctx.socket(zmq.XSUB)
        xpub = self._ctx.socket(zmq.XPUB)
        router = self._ctx.socket(zmq.ROUTER)
        for sock in (xsub, xpub):
            sock.sndhwm = self._hwm
            sock.rcvhwm = self._hwm
            sock.linger = 0
        router.linger = 0
        router.router_mandatory = True
        # a frame over the limit makes libzmq drop the connection of the peer that sent it: it never reaches
        # Python, the proxy or any subscriber (nodes count what still exceeds their own limit)
        for sock in (xsub, router):
            sock.maxmsgsize = self._max_msg_bytes
        try:
            pub = self._bind(xsub, self._requested.pub)
            sub = self._bind(xpub, self._requested.sub)
            latch = self._bind(router, self._requested.latch)
        except BusError:
            for sock in (xsub, xpub, router):
                sock.close(0)
            self._shutdown_ctx()
            raise
        self.address = BusAddress(pub, sub, latch)
        # subscribe the proxy itself to the graph's latched topics: XSUB forwards subscriptions to every
        # publisher (and to later ones), so they send these topics even when no subscriber exists yet, which is
        # when the late joiner the cache exists for most needs them
        for topic in self._latched_topics:
            xsub.send(b"\x01" + topic.encode())
        # and to a topic nobody publishes: a publisher that attaches then always hears at least one
        # subscription, and stops waiting for them at once instead of after its 100 ms grace (which every node
        # paid at start while nothing was subscribed yet)
        xsub.send(b"\x01" + ATTACH_MARK)

        capture: zmq.Socket[bytes] | None = None
        capture_sub: zmq.Socket[bytes] | None = None
        if self._latched_topics:
            capture = self._ctx.socket(zmq.PUB)
            capture.linger = 0
            capture.bind("inproc://palpa-capture")
            capture_sub = self._ctx.socket(zmq.SUB)
            capture_sub.linger = 0
            capture_sub.connect("inproc://palpa-capture")
            for topic in self._latched_topics:
                capture_sub.setsockopt(zmq.SUBSCRIBE, topic.encode())
        control, self._control = self._pair("inproc://palpa-proxy-control")
        # stop() wakes the cache thread at once instead of after its poll's 100 ms
        wake, self._wake = self._pair("inproc://palpa-lvc-wake")

        def proxy() -> None:
            try:
                zmq.proxy_steerable(xsub, xpub, capture, control)
            except zmq.ZMQError as exc:  # context terminated
                log.debug("proxy ended: %s", exc)
            finally:
                for sock in (xsub, xpub, control):
                    sock.close(0)
                if capture is not None:
                    capture.close(0)

        def cache() -> None:
            try:
                self._serve_cache(router, capture_sub, wake)
            finally:
                wake.close(0)
                router.close(0)
                if capture_sub is not None:
                    capture_sub.close(0)

        for target, name in ((proxy, "palpa-proxy"), (cache, "palpa-lvc")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return self.address

    def _pair(self, endpoint: str) -> tuple[zmq.Socket[bytes], zmq.Socket[bytes]]:
        """Two connected PAIR sockets on ``endpoint``: (the thread's end, the caller's end)."""
        ends = (self._ctx.socket(zmq.PAIR), self._ctx.socket(zmq.PAIR))
        for sock in ends:
            sock.linger = 0
        ends[0].bind(endpoint)
        ends[1].connect(endpoint)
        return ends

    def _serve_cache(self, router: zmq.Socket[bytes], capture_sub: zmq.Socket[bytes] | None,
                     wake: zmq.Socket[bytes]) -> None:
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(wake, zmq.POLLIN)
        exact = {t.encode() for t in self._latched_topics}
        if capture_sub is not None:
            poller.register(capture_sub, zmq.POLLIN)
        keys_generation = 0
        while not self._stop.is_set():
            if self.clients is not None and self.clients.generation != keys_generation:
                keys_generation = self.clients.generation
                self._publish_client_keys(router, self.clients.listing())
            events = dict(poller.poll(100))
            if capture_sub is not None and capture_sub in events:
                while True:
                    try:
                        frames = capture_sub.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    if len(frames) >= 3 and frames[0] in exact:
                        self._guarded(self._store, None, frames[0], frames[1:])
            if router in events:
                while True:
                    try:
                        msg = router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._guarded(self._handle_latch, router, [f.bytes for f in msg], peer_of(msg[-1]))

    def _guarded(self, handle: Callable[..., object], *args: Any) -> None:
        """Run one request's handling; whatever it raises is counted and logged, and the cache thread goes on
        (everything the graph's readiness, services and late joiners need runs on it)."""
        try:
            handle(*args)
        except Exception as exc:  # noqa: BLE001 - no input may end the cache thread
            self.internal_errors += 1
            self._throttle.event("internal", logging.ERROR, "latch: error handling a request (%d so far): %r",
                                 self.internal_errors, exc)

    def _handle_latch(self, router: zmq.Socket[bytes], frames: list[bytes], peer: bytes | None = None) -> None:
        """One request from the client ``frames[0]`` (its ROUTER identity) of ``peer`` (:func:`peer_of`; None:
        a peer of its own)."""
        if len(frames) < 2:
            log.warning("latch: ignoring a request of %d frame(s)", len(frames))
            return
        ident, verb = frames[0], frames[1]
        topic = frames[2] if len(frames) > 2 else b""
        if verb == b"SET":
            if not self._store(router, topic, frames[3:], ident, peer):
                return
            for prefix, watcher in self._watchers.matching(topic):
                if watcher != ident:
                    self._send(router, prefix, watcher, [b"VAL", topic, *frames[3:]])
        elif verb == b"GET":
            if len(topic) > MAX_TOPIC_BYTES:
                self.watch_refused += 1
                self._refuse(router, ident, topic, f"GET prefix of {len(topic)} bytes (at most {MAX_TOPIC_BYTES})",
                             watch=True)
                return
            evicted_before = self._watchers.evicted
            why = self._watchers.add(topic, ident, peer)
            if why is not None:
                self.watch_refused += 1
                self._refuse(router, ident, topic, f"watcher table {why}", watch=True)
            elif self._watchers.evicted != evicted_before:
                self._throttle.event("watch-evicted", logging.WARNING, "latch: watcher table full (%d watches): "
                                     "dropped the oldest watch of the client holding the most (%d so far)",
                                     len(self._watchers), self._watchers.evicted)
            with self._cache_lock:
                hits = self._cache.matching(topic)
            for cached_topic, value in hits:
                self._send(router, topic, ident, [b"VAL", cached_topic, *value])
        elif verb == b"UNWATCH":
            self._watchers.discard(topic, ident)
        elif verb == b"PING":
            self._send(router, b"", ident, [b"PONG", topic])
        else:
            log.warning("latch: ignoring unknown request %r (%d frames)", verb[:16], len(frames))
            self._send(router, b"", ident, [b"ERR", b"", b"unknown request (expected SET, GET, UNWATCH or PING)"])

    def _publish_client_keys(self, router: zmq.Socket[bytes], listing: bytes) -> None:
        """Cache the authorised client keys (read at start and on every reload) and push them to whoever asked:
        direct CURVE publishers let in exactly these (palpa.net.direct)."""
        value = [b"", listing]
        with self._cache_lock:
            why, _ = self._cache.put(CLIENT_KEYS_TOPIC, value)
        if why is not None:
            log.error("latch: cannot cache the authorised client keys: %s", why)
            return
        for prefix, watcher in self._watchers.matching(CLIENT_KEYS_TOPIC):
            self._send(router, prefix, watcher, [b"VAL", CLIENT_KEYS_TOPIC, *value])

    def _store(self, router: zmq.Socket[bytes] | None, topic: bytes, value: list[bytes],
               ident: bytes = BUS_OWNER, peer: bytes | None = None) -> bool:
        """Check and cache one value (owned by ``ident`` of ``peer``; a captured one by the bus); a refusal is
        counted, logged and (to a SET's sender) answered with ``ERR topic reason``."""
        evicted: list[bytes] = []
        with self._cache_lock:
            why = self._cache.check(topic, value)
            if why is None:
                why, evicted = self._cache.put(topic, value, ident, peer)
            if why is not None:
                self._cache.refused += 1
        if evicted:
            self._throttle.event("evicted", logging.WARNING, "latch: cache full: evicted %d value(s) of the client "
                                 "holding the most (last %r) to keep %r", len(evicted), evicted[-1][:80], topic[:80])
        if why is None:
            return True
        self._refuse(router, ident, topic, why)
        return False

    def _refuse(self, router: zmq.Socket[bytes] | None, ident: bytes, topic: bytes, why: str,
                watch: bool = False) -> None:
        """Log a refused request (throttled, SETs and watches apart, each with its own count) and answer its sender
        ``ERR topic reason``."""
        kind, count = ("watch refused", self.watch_refused) if watch else ("refused", self._cache.refused)
        self._throttle.event(kind, logging.WARNING, f"latch: {kind} %r (%d so far): %s", topic[:80], count, why)
        if router is not None:
            self._send(router, b"", ident, [b"ERR", topic[:MAX_TOPIC_BYTES], why.encode()])

    @property
    def latch_refused(self) -> int:
        """SETs (and captured values) the cache refused: malformed, not latched, or over its bounds."""
        with self._cache_lock:
            return self._cache.refused

    def _send(self, router: zmq.Socket[bytes], prefix: bytes, ident: bytes, frames: list[bytes]) -> None:
        try:
            router.send_multipart([ident, *frames], zmq.NOBLOCK)
        except zmq.ZMQError:  # the asker is gone (or not keeping up): forget it
            self._watchers.discard(prefix, ident)

    def cached_topics(self) -> list[str]:
        """Topics with a cached last value."""
        with self._cache_lock:
            return sorted(t.decode(errors="replace") for t in self._cache.values
                          if not t.startswith(DIRECTORY_PREFIX) and t != CLIENT_KEYS_TOPIC)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the proxy and the cache, close every socket and remove ipc socket files."""
        self._stop.set()
        if self.address is not None:
            with contextlib.suppress(zmq.ZMQError):
                self._control.send(b"TERMINATE")
            with contextlib.suppress(zmq.ZMQError):
                self._wake.send(b"", zmq.NOBLOCK)
        for thread in self._threads:
            thread.join(timeout_s)
        if self.address is not None:
            self._control.close(0)
            self._wake.close(0)
        self._shutdown_ctx()
        if self.address is not None:
            for endpoint in (self.address.pub, self.address.sub, self.address.latch):
                if endpoint.startswith("ipc://"):
                    Path(endpoint[len("ipc://") :]).unlink(missing_ok=True)

    def _shutdown_ctx(self) -> None:
        if self._auth is not None:
            self._auth.stop()
            self._auth = None
        self._ctx.term()

    def __enter__(self) -> Bus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
