"""The Node API: publishers, typed subscriptions (callback or iterator), timers, parameters, heartbeats.

A node is a small class::

    class Talker(Node):
        class Params(palpa.Params):
            rate_hz: float = 10.0

        def setup(self) -> None:
            self.out = self.publisher("chatter", Text)
            self.timer(1.0 / self.params.rate_hz, self.tick)

        def tick(self) -> None:
            self.out.publish(Text(text="hello"))

and ``palpa.run_node(Talker)`` is its ``main()``. A bare ``Node(name="script")`` is also an iterator source:
``for msg in node.subscribe("camera/indenters", IndenterDisplacements): ...``.

Bad input never kills a node: a malformed frame, an unknown or wrong type, or a payload that does not validate is
counted on its topic and logged at most every few seconds with what was wrong (the field path).

The node's collaborators live apart, and its declarations go to them: its publishers, subscriptions and services,
and the rules of declaring them, in :mod:`palpa.node.inventory`; its timers and simulation-clock side in
:mod:`palpa.node.node_time`; its readiness, heartbeats and bus logging in :mod:`palpa.node.presence`; topic naming in
:mod:`palpa.node.naming`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, TypeVar

from palpa import env as palpa_env
from palpa.message import Message
from palpa.net.address import BusAddress
from palpa.net.connect import bus_transport
from palpa.net.transport import Transport, TransportOptions
from palpa.net.wire import Header, TopicStats
from palpa.node.dispatch import Dispatch
from palpa.node.endpoints import DEFAULT_BATCH, MsgInfo, Publisher, RawMessage, Subscription, Timer
from palpa.node.inventory import Inventory
from palpa.node.naming import default_node_name, resolve_topic
from palpa.node.node_time import SimTime, Timers, clock_timeout_ns
from palpa.node.params import Params as ParamsBase
from palpa.node.params import convert_params
from palpa.node.params_runtime import ParamServer
from palpa.node.presence import (
    JOIN_TIMEOUT_S,
    BusLogHandler,
    Heartbeats,
    confirm_subscriptions,
    take_reach_answers,
)
from palpa.node.presence import LOG_TEXT_MAX as LOG_TEXT_MAX  # re-exported: it was defined here
from palpa.node.receive import Receiver
from palpa.node.resources import C, Resources
from palpa.node.service import DEFAULT_TIMEOUT_S, Responder, Service
from palpa.node.service_client import Client
from palpa.node.stateguard import check_state_kept, own_state
from palpa.timing.clock import Clock, SystemClock, TopicClock

__all__ = ["DEFAULT_BATCH", "MsgInfo", "Node", "Publisher", "RawMessage", "Subscription", "Timer", "resolve_topic"]

M = TypeVar("M", bound=Message)
Q = TypeVar("Q", bound=Message)
R = TypeVar("R", bound=Message)


class _NoParams(ParamsBase):
    pass


class Node:
    """Base class of every node. Override :meth:`setup` to declare publishers, subscriptions and timers."""

    Params: ClassVar[type[ParamsBase]] = _NoParams
    params: ParamsBase
    """This node's parameters, validated into :attr:`Params`. A subclass declaring ``class Params`` also declares
    ``params: Params`` so that mypy checks every ``self.params.<name>`` (tests/test_architecture.py holds every
    node class in the project to it)."""

    def __init__(
        self,
        name: str | None = None,
        params: Mapping[str, Any] | ParamsBase | None = None,
        *,
        transport: Transport | None = None,
        clock: Clock | None = None,
        namespace: str = "",
        remap: Mapping[str, str] | None = None,
        bus: str | BusAddress | None = None,
        heartbeat_s: float = 1.0,
        sim_clock: bool | None = None,
        wait_for_clock_s: float = 30.0,
        transport_options: TransportOptions | None = None,
        sim_clock_timeout_s: float | None = None,
        serve_params: bool | None = None,
    ) -> None:
        theirs = set(vars(self))   # what a subclass's __init__ set before calling this one
        self.name = name or default_node_name(type(self).__name__)
        self.incarnation = int.from_bytes(os.urandom(4), "big") | 1
        """Drawn anew at every start and sent in every header (``inc``): receivers tell a restart from a repeat."""
        self.refusals: dict[str, int] = {}
        """Inputs this node refused and counted, by kind (``clock_jump``: ticks past the bound; the lockstep clock's
        ``clock_ack/<why>``; bad messages are counted per topic apart): in its heartbeats (``refused``), shown by
        ``palpa node info``."""
        if sim_clock is None:
            sim_clock = palpa_env.flag(palpa_env.SIM_CLOCK)
        self.params = convert_params(type(self).Params, params, where=f"node {self.name!r}")
        self._topic_clock = TopicClock() if sim_clock and clock is None else None
        timeout_ns = clock_timeout_ns(sim_clock_timeout_s)
        self.clock: Clock = clock or self._topic_clock or SystemClock()
        self.namespace = namespace.strip("/")
        self.remap = dict(remap or {})
        if transport is None:
            transport = bus_transport(bus, transport_options)
        self._transport = transport
        self.log = logging.getLogger(f"palpa.node.{self.name}")
        self._resources = Resources(self.log)
        self.dispatch = Dispatch(self.log)
        """Runs every callback of this node (exception isolation, batches flushed when callbacks return)."""
        options = getattr(transport, "options", None)
        self._rx = Receiver(self.dispatch, self.log, getattr(options, "max_msg_bytes", 0))
        self._inventory = Inventory(self, self._rx, self.incarnation, self._topic_clock is not None)
        self._timers = Timers(self)
        self._shutdown = False
        self._closed = False
        self.exit_code = 0
        self._bus_handler = BusLogHandler(self)
        self.log.addHandler(self._bus_handler)
        self._heartbeats = Heartbeats(self, heartbeat_s, self._rx, self._inventory.pubs, self._inventory.services)
        take_reach_answers(self, self._rx)
        self._set_up = False
        self._probe = ""
        """This node's readiness probe once the bus echoed it (``<name>/<pid>.<incarnation>``; ClockAck.probe)."""
        self._sim_time: SimTime | None = None
        """This node's side of the simulation clock (on one): ticks, instants, lockstep acks."""
        if self._topic_clock is not None:
            self._sim_time = SimTime(self, self._topic_clock, self._timers, self._rx, self._inventory.pubs,
                                     self._inventory.raw_sent, timeout_ns)
            self._sim_time.await_first_tick(wait_for_clock_s)
        if heartbeat_s > 0 if serve_params is None else serve_params:
            ParamServer(self, lambda: self.params, self._change_params)
        try:
            own = own_state(self, theirs)
            self.setup()
            check_state_kept(self, self.name, own)
            self._probe = confirm_subscriptions(self, self._rx, self.incarnation, JOIN_TIMEOUT_S)
        except BaseException:
            # a refused plan must not leave a robot connection or a serial port open behind it
            self._release(linger_ms=0)
            raise
        self._set_up = True

    @property
    def transport(self) -> Transport:
        """The connection to the bus (ZeroMQ, or in memory under :mod:`palpa.testing`)."""
        return self._transport

    @property
    def closed(self) -> bool:
        """True once the sockets are closed (after :meth:`close`, or a failed :meth:`setup`)."""
        return self._closed

    @property
    def handler_errors(self) -> int:
        """Callbacks that raised so far (each was logged; the node went on)."""
        return self.dispatch.errors

    # -- declaration -------------------------------------------------------------------------------
    def setup(self) -> None:
        """Declare publishers, subscriptions and timers here (``self.params`` is ready)."""

    def on_shutdown(self) -> None:
        """Called once before the node's sockets close: stop hardware, flush files. Not called when
        :meth:`setup` raised (only what :meth:`closing` registered is released then)."""

    def closing(self, resource: C) -> C:
        """Register ``resource`` (anything with ``close()``) to be closed when the node closes, after
        :meth:`on_shutdown`, or at once if :meth:`setup` raises; returns it. Resources close in reverse order of
        registration; a failing ``close()`` is logged and does not keep the others (or the sockets) open.

        Register a driver before connecting it: ``self.driver = self.closing(make_driver()); self.driver.connect()``.
        """
        return self._resources.add(resource)

    def on_params_changed(self, old: Any, new: Any) -> bool | None:
        """Called when ``palpa param set`` (or a ParamSet request) would change ``self.params`` from ``old`` to
        ``new``, both validated instances of this node's :attr:`Params` (a subclass annotates them so:
        ``def on_params_changed(self, old: Talker.Params, new: Talker.Params)``): apply what needs applying
        (re-time a timer) and return None, or refuse the whole change by returning False or raising
        :class:`palpa.ParamError` with the reason. Only parameters declared :data:`palpa.RunTime` ever reach it:
        a change of any other is refused before (palpa.node.params_runtime)."""
        return None

    def _change_params(self, old: ParamsBase, new: ParamsBase) -> bool:
        if self.on_params_changed(old, new) is False:
            return False
        self.params = new
        return True

    def service(
        self, name: str, request_type: type[Q], response_type: type[R], handler: Callable[[Q], R | Responder[R]]
    ) -> Service[Q, R]:
        """Serve ``name`` with ``handler(request) -> response`` (deferred answers, refusals: :mod:`palpa.node.service`)."""
        return self._inventory.service(name, request_type, response_type, handler)

    def client(
        self, name: str, request_type: type[Q], response_type: type[R], *, timeout_s: float = DEFAULT_TIMEOUT_S
    ) -> Client[Q, R]:
        """A caller of service ``name``: ``call(req)`` (blocking, safe in callbacks) or ``call_async(req)``."""
        return Client(self, name, request_type, response_type, timeout_s=timeout_s)

    def resolve(self, topic: str) -> str:
        """The topic name on the bus after remapping and namespacing (``/x`` is absolute; ``_palpa/`` is global)."""
        return resolve_topic(topic, self.namespace, self.remap)

    def publisher(
        self, topic: str, msg_type: type[M], *, latched: bool = False, batch: int | None = None,
        direct: bool | None = None,
    ) -> Publisher[M]:
        """A publisher of ``msg_type`` on ``topic``. Latched topics are replayed to subscribers that join late.

        Inside callbacks, messages are coalesced up to ``batch`` (default :data:`DEFAULT_BATCH`) per ZeroMQ message
        and sent when the callback returns. An explicit ``batch > 1`` also batches outside callbacks (flush with
        ``Publisher.flush()`` or the node's loop); ``batch=1`` never batches.

        ``direct=True`` sends straight to the subscribers instead of through the bus's proxy (lower latency, see
        :mod:`palpa.net.direct`); None leaves it to the transport options (launch ``transport: {direct: [...]}``).
        """
        return self._inventory.publisher(topic, msg_type, latched=latched, batch=batch, direct=direct)

    def publish_raw(
        self, topic: str, header: Header, payload: bytes, blobs: Sequence[bytes] = (), *, latched: bool = False
    ) -> None:
        """Send an already-encoded payload with a caller-made header (the player keeps recorded sequence numbers,
        types and publisher names). ``topic`` is used as given (no remapping); nothing is validated."""
        self._inventory.publish_raw(topic, header, payload, blobs, latched=latched)

    def subscribe(
        self,
        topic: str,
        type_or_callback: type[M] | Callable[[M], object] | Callable[[M, MsgInfo], object],
        callback: Callable[[M], object] | Callable[[M, MsgInfo], object] | None = None,
        *,
        queue_size: int = 1000,
    ) -> Subscription[M]:
        """Subscribe to ``topic``: ``subscribe(t, self.on_msg)`` (type from the annotation),
        ``subscribe(t, Type, cb)``, or ``subscribe(t, Type)`` to iterate. A callback with a second parameter
        annotated :class:`MsgInfo` gets ``(msg, info)``: the header and blobs of that very message (rather than
        ``sub.last_header`` / ``sub.last_blobs``, which only say what came last)."""
        return self._inventory.subscribe(topic, type_or_callback, callback, queue_size=queue_size)

    def subscribe_raw(self, prefix: str, callback: Callable[[RawMessage], object], *,
                      topics: Callable[[str], bool] | None = None) -> None:
        """Every envelope whose topic starts with ``prefix`` (``""`` for all), undecoded; with ``topics``, only
        those on a topic it accepts (asked once per topic: the others are dropped before any decoding, unseen
        and uncounted, and no direct publisher of them is connected to)."""
        self._inventory.subscribe_raw(prefix, callback, topics=topics)

    def timer(
        self, period_s: float, callback: Callable[[], object], *, oneshot: bool = False,
        first_in_s: float | None = None,
    ) -> Timer:
        """Call ``callback`` every ``period_s`` seconds of node-clock time (first after ``first_in_s``)."""
        return self._timers.add(period_s, callback, oneshot, first_in_s)

    # -- running -----------------------------------------------------------------------------------
    @property
    def is_shutdown(self) -> bool:
        return self._shutdown

    def request_shutdown(self, exit_code: int | None = None) -> None:
        """Ask the loop to stop (optionally with the process exit code); safe from signal handlers."""
        if exit_code is not None:
            self.exit_code = exit_code
        self._shutdown = True

    def next_timer_due_ns(self) -> int | None:
        """When the earliest live timer fires (node-clock ns), or None (also once shutdown was requested)."""
        return None if self._shutdown else self._timers.next_due_ns()

    def spin_once(self, timeout_s: float = 0.0) -> None:
        """Wait up to ``timeout_s`` for input (less if a timer is due sooner; not at all with 0), then dispatch what
        has arrived and run the due timers. Messages are handled before timers so that a timer which checks data
        freshness (a watchdog) never judges by a queue the node had no chance to read."""
        # a node about to block skips this: the wait below returns at once with what is there, or when a timer is
        # due (a sim-clock node's come due only with a tick), and then dispatches and runs timers in that order
        # (one poll per wake-up: a lockstep clock and its nodes wake thousands of times a simulated minute)
        skipped = timeout_s > 0
        if not skipped:
            for delivery in self._transport.poll(0):
                self._rx.dispatch(delivery)
            self.run_timers()
        if self._set_up:  # a heartbeat says "ready": set up, subscriptions confirmed (what a launcher waits for)
            self._heartbeats.beat()
        if not skipped and timeout_s <= 0:  # no wait (an executor's pass over its nodes): nothing below to block
            if self._sim_time is not None:
                self._sim_time.check_alive()
                self._report_to_clock()
            return
        if not self.clock.is_real():
            timeout_s = 0.0 if self._timers else timeout_s
        elif self._topic_clock is None and (due := self.next_timer_due_ns()) is not None:
            # (simulated time moves only when a tick arrives: a sim-clock node just waits for input)
            timeout_s = max(0.0, min(timeout_s, (due - self.clock.now_ns()) / 1e9))
        if self._set_up:
            timeout_s = self._heartbeats.wait_s(timeout_s)
        if timeout_s > 0 or skipped:
            self._report_to_clock()  # before blocking: the clock may be waiting for what was just handled
            for delivery in self._transport.poll(timeout_s):
                self._rx.dispatch(delivery)
            self.run_timers()
        if self._sim_time is not None:
            self._sim_time.check_alive()
        self._report_to_clock()

    @property
    def sim_time(self) -> SimTime | None:
        """This node's side of a simulation clock (None: not on one): the jumps it refused, among others."""
        return self._sim_time

    def _report_to_clock(self) -> None:
        if self._sim_time is not None and self._set_up:
            self._sim_time.report(self._probe)

    def spin(self) -> None:
        """Run until :meth:`request_shutdown` (or a signal, under :func:`palpa.run_node`)."""
        while not self._shutdown:
            self.spin_once(0.1)

    def close(self, linger_s: float = 0.5) -> None:
        """Call :meth:`on_shutdown`, then close the sockets with a bounded linger. Idempotent."""
        if self._closed:
            return
        self._shutdown = True
        try:
            self.on_shutdown()
            for srv in self._inventory.services.values():
                srv.withdraw()
            if self._set_up:
                self._heartbeats.leave()
            if self._sim_time is not None:  # the lockstep clock stops waiting for this node now, not later
                self._sim_time.leave()
            self.flush()
        finally:
            self._release(int(linger_s * 1000))

    def _release(self, linger_ms: int) -> None:
        """Close the registered resources, then the sockets."""
        self._shutdown = True
        try:
            self._resources.close()
        finally:
            self._closed = True
            self.log.removeHandler(self._bus_handler)
            self._transport.close(linger_ms)

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def instant_ns(self) -> int:
        """The simulated instant this node is at, for ``Header.at`` of what it sends (0: not on a simulation
        clock)."""
        return self._topic_clock.now_ns() if self._topic_clock is not None else 0

    # -- internals ---------------------------------------------------------------------------------
    def run_timers(self) -> None:
        """Run the timers due at the current time (an executor's step, see palpa.timing.compose), again while a callback
        started one due at once: afterwards none is due. Not while shutting down, nor while a simulation clock
        holds time."""
        if self._shutdown or (self._sim_time is not None and self._sim_time.holds_timers):
            return
        self._timers.run(self.clock.now_ns())

    def flush(self) -> None:
        """Send every batched message still pending."""
        self.dispatch.flush()

    def count_bad_raw(self, topic: str) -> None:
        """Count a message on raw-subscribed ``topic`` that its reader found malformed (the recorder keeps such
        messages, and says so in the counters)."""
        stats = self._rx.raw_stats.get(topic)
        if stats is not None:
            stats.decode_errors += 1

    def counters(self) -> dict[str, TopicStats]:
        """Receive counters per subscribed topic (typed and raw; the typed ones where a topic has both)."""
        return self._rx.counters()

    def _heartbeat(self) -> None:
        """Send this node's heartbeat now (they go out by themselves every ``heartbeat_s`` once it is set up)."""
        self._heartbeats.send()

