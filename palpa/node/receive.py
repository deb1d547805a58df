"""The receive path of a node: exact topic matching, sequence tracking, decoding, and counting what is bad.

ZeroMQ matches subscriptions by prefix; here each envelope goes to the subscription of exactly its topic (and to
raw subscriptions whose prefix matches), duplicates and gaps are counted per publisher, and a malformed frame, an
unknown type or an invalid payload is counted and logged with what was wrong: it never reaches a callback and
never stops the node. Callbacks run through the node's :class:`~palpa.node.dispatch.Dispatch` (exception isolation,
batching depth); the receiver never sees the node itself.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, NamedTuple

from palpa.errors import DecodeError
from palpa.lograte import LogThrottle
from palpa.net.transport import Delivery
from palpa.net.wire import (
    COUNTER_MAX,
    DECODE_ERRORS,
    MAX_MSG_BYTES,
    MAX_TOPIC_BYTES,
    MAX_TRACKED_PUBLISHERS,
    Envelope,
    Header,
    SequenceTracker,
    TopicStats,
    parse_envelope,
)
from palpa.node.dispatch import Dispatch
from palpa.node.endpoints import MsgInfo, RawMessage, Subscription

__all__ = ["Receiver"]

_ERROR_LOG_INTERVAL_NS = 5_000_000_000
_ERROR_TEXT_MAX = 300
_ROUTES_MAX = 4096  # topics remembered (ours or not); an attacker inventing topic names only costs a re-scan


class _RawSubscription(NamedTuple):
    prefix: bytes
    callback: Callable[[RawMessage], object]
    accept: Callable[[str], bool] | None = None


class _Route(NamedTuple):
    topic: str
    sub: Subscription[Any] | None
    raws: tuple[Callable[[RawMessage], object], ...]
    rstats: TopicStats | None


_NO_ROUTE = object()


class Receiver:
    """Routes a node's received envelopes to its subscriptions; one per node.

    ``max_bytes`` bounds an envelope (0: :data:`palpa.net.wire.MAX_MSG_BYTES`); ``log`` gets the rate-limited reports
    of bad input."""

    def __init__(self, dispatch: Dispatch, log: logging.Logger, max_bytes: int = 0) -> None:
        self._dispatch = dispatch
        self._log = log
        self.subs: dict[bytes, Subscription[Any]] = {}
        self.raw: list[_RawSubscription] = []
        self.routes: dict[bytes, _Route | None] = {}
        self.raw_stats: dict[str, TopicStats] = {}
        self._throttle = LogThrottle(log)
        self._tracker = SequenceTracker(on_forget=self._forgot)
        self._raw_tracker = SequenceTracker(on_forget=self._forgot)
        self._last_error_log: dict[str, int] = {}
        self.max_bytes: int = max_bytes or MAX_MSG_BYTES
        self.on_instant: Callable[[int], object] | None = None
        """Called with ``Header.at`` of every live (not cached) envelope that has one, before it is handled."""
        self.internal_errors = 0
        """Envelopes whose handling raised where nothing should (a receive-path bug): counted, logged, survived."""

    def _forgot(self, topic: str, node: str) -> None:
        self._throttle.event("forgot", logging.WARNING, "sequence state full (%d publisher-topic pairs): forgot %r "
                             "on %r, the least recently heard (its next message counts as its first)",
                             MAX_TRACKED_PUBLISHERS, node, topic)

    @property
    def publishers_forgotten(self) -> int:
        """(topic, publisher) pairs whose sequence state was forgotten to stay within MAX_TRACKED_PUBLISHERS."""
        return self._tracker.forgotten + self._raw_tracker.forgotten

    def add(self, key: bytes, sub: Subscription[Any]) -> None:
        """Deliver envelopes on exactly topic ``key`` to ``sub``."""
        self.subs[key] = sub
        self.routes.clear()

    def add_raw(self, prefix: bytes, callback: Callable[[RawMessage], object],
                accept: Callable[[str], bool] | None = None) -> None:
        """Hand every envelope whose topic starts with ``prefix`` (and, with ``accept``, passes it) to
        ``callback``, undecoded."""
        self.raw.append(_RawSubscription(prefix, callback, accept))
        self.routes.clear()

    def remove_raw(self, prefix: bytes) -> None:
        """Stop handing envelopes under ``prefix`` to the raw callbacks added for it."""
        self.raw = [r for r in self.raw if r.prefix != prefix]
        self.routes.clear()

    def count_error(self, topic: str, stats: TopicStats, text: str) -> None:
        """Count a bad message on ``topic``; log it, at most once per topic every five seconds."""
        stats.decode_errors = min(COUNTER_MAX, stats.decode_errors + 1)
        stats.last_error = text = text if len(text) <= _ERROR_TEXT_MAX else text[:_ERROR_TEXT_MAX] + "..."
        now = time.monotonic_ns()
        if now - self._last_error_log.get(topic, -_ERROR_LOG_INTERVAL_NS) >= _ERROR_LOG_INTERVAL_NS:
            self._last_error_log[topic] = now
            self._log.warning("dropped a bad message on %r (%d so far): %s", topic, stats.decode_errors, text)

    def _route(self, topic_b: bytes) -> _Route | None:
        """Who gets messages on this exact topic (cached per topic; None: a prefix match that is not ours)."""
        route = self.routes.get(topic_b, _NO_ROUTE)
        if route is _NO_ROUTE:
            if len(topic_b) > MAX_TOPIC_BYTES:  # no subscription has such a name; parse_envelope refuses it
                return None
            sub = self.subs.get(topic_b)
            raws = tuple(r.callback for r in self.raw if topic_b.startswith(r.prefix) and
                         (r.accept is None or r.accept(topic_b.decode(errors="replace"))))
            if sub is None and not raws:
                route = None
            else:
                topic = topic_b.decode(errors="replace")
                rstats = self.raw_stats.setdefault(topic, TopicStats()) if raws else None
                route = _Route(topic, sub, raws, rstats)
            if len(self.routes) >= _ROUTES_MAX:
                self.routes.clear()
            self.routes[topic_b] = route
        return route  # type: ignore[return-value]

    def dispatch(self, delivery: Delivery) -> None:
        """Hand one received envelope to the subscriptions of its exact topic (typed and raw). Nothing a peer
        sends stops the node: what the checks below miss is counted in :attr:`internal_errors` and logged."""
        try:
            self._handle(delivery)
        except Exception as exc:
            self.internal_errors += 1
            self.count_error("(receive)", TopicStats(), f"internal error on {delivery.frames[0][:80]!r}: {exc!r}")

    def _handle(self, delivery: Delivery) -> None:
        frames = delivery.frames
        topic_b, routes = frames[0], self.routes
        route = routes[topic_b] if topic_b in routes else self._route(topic_b)  # no call for the cached route
        if route is None:
            return
        topic, sub, raws, rstats = route
        size = sum(map(len, frames))
        if size > self.max_bytes:
            stats = sub.stats if sub is not None else rstats
            if stats is not None:
                self.count_error(topic, stats, f"message of {size} bytes refused (max_msg_bytes {self.max_bytes})")
            return
        try:
            env = delivery.envelope
            if env is None:  # the first receiver of a shared delivery parses it for the others (Delivery)
                env = delivery.envelope = parse_envelope(frames)
            items = env.messages() if rstats is not None else None
        except DecodeError as exc:
            stats = sub.stats if sub is not None else rstats
            if stats is not None:
                self.count_error(topic, stats, str(exc))
            return
        cached = delivery.from_cache
        at = env.headers[0].at
        if at and not cached and self.on_instant is not None:
            self.on_instant(at)
        if items is not None and rstats is not None:
            tracker = self._raw_tracker
            for header, payload, blobs in items:
                if not (cached and tracker.seen_at_least(topic, header.node, header.seq, header.inc)) and \
                        tracker.observe(topic, header.node, header.seq, rstats, header.inc):
                    raw = RawMessage(topic, header, payload, blobs, cached, time.time_ns())
                    for callback in raws:
                        self._dispatch.call(callback, raw)
        if sub is None:
            return
        if not env.batch:
            self._deliver(sub, topic, env.headers[0], env.payload, env.blobs, cached)
        elif cached or not self._deliver_batch(sub, topic, env):
            try:
                items = items if items is not None else env.messages()
            except DecodeError as exc:
                self.count_error(topic, sub.stats, str(exc))
                return
            for header, payload, blobs in items:
                self._deliver(sub, topic, header, payload, blobs, cached)

    def _deliver_batch(self, sub: Subscription[Any], topic: str, env: Envelope) -> bool:
        """The common batch (one publisher, consecutive sequence numbers after the last seen, the subscribed
        type, every payload valid) decoded in one call and handed over in one loop. False when it is not that
        batch: nothing was recorded and the caller goes message by message."""
        headers = env.headers
        first = headers[0]
        n = len(headers)
        if [h.seq for h in headers] != list(range(first.seq, first.seq + n)) or \
                any(h.node != first.node or h.type != sub.type_name or h.inc != first.inc for h in headers):
            return False
        try:
            msgs = sub.batch_decoder.decode(env.payload)
        except DECODE_ERRORS:
            return False
        if len(msgs) != n or not self._tracker.observe_run(topic, first.node, first.seq, n, sub.stats, first.inc):
            return False
        sub.last_blobs = []
        callback = sub.callback
        if callback is None:
            sub.last_header = headers[-1]
            sub.queue.extend(msgs)
            return True

        with_info = sub.with_info

        def deliver(i: int) -> None:
            sub.last_header = headers[i]
            if with_info:
                callback(msgs[i], MsgInfo(headers[i], [], False))
            else:
                callback(msgs[i])

        self._dispatch.call_each(deliver, n, callback)
        return True

    def _deliver(self, sub: Subscription[Any], topic: str, header: Header, payload: bytes,
                 blobs: list[bytes], cached: bool) -> None:
        if cached and self._tracker.seen_at_least(topic, header.node, header.seq, header.inc):
            return
        if header.type != sub.type_name:
            self.count_error(topic, sub.stats, f"expected type {sub.type_name}, got {header.type}")
            return
        try:
            msg = sub.decoder.decode(payload)
        except DECODE_ERRORS as exc:
            self.count_error(topic, sub.stats, f"{header.type}: {exc}")
            return
        # sequence numbers count only once the message is valid: garbage cannot fake gaps or restarts
        if not self._tracker.observe(topic, header.node, header.seq, sub.stats, header.inc):
            return
        sub.last_header = header
        sub.last_blobs = blobs
        if sub.callback is not None:
            if sub.with_info:
                self._dispatch.call(sub.callback, msg, MsgInfo(header, blobs, cached))
            else:
                self._dispatch.call(sub.callback, msg)
        else:
            sub.queue.append(msg)

    def counters(self) -> dict[str, TopicStats]:
        """Receive counters per subscribed topic (typed and raw; the typed ones where a topic has both)."""
        out = dict(self.raw_stats)
        out.update({s.topic: s.stats for s in self.subs.values()})  # typed ones also count decode errors
        return out
