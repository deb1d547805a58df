"""A node's time: its timers, and its side of a simulation clock (ticks, instants, lockstep acks).

:class:`palpa.node.node.Node` owns one :class:`Timers` and, on a simulation clock (``--sim-clock``), one
:class:`SimTime`. They are apart from the node because they are one mechanism with its own state, read in one
place: when time moves (a tick from the clock node, :mod:`palpa.timing.simclock`, or a message stamped with a later
instant), the timers due then run, and the node tells the lockstep clock (:mod:`palpa.timing.lockstep`) what it has done
at that time. The node's loop calls in with :meth:`SimTime.report` (before it blocks and after each wake-up) and
:meth:`SimTime.check_alive` (a clock that stopped ticking stops the node).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import msgspec

from palpa import env as palpa_env
from palpa.errors import PalpaError
from palpa.net.transport import ZmqTransport
from palpa.net.wire import TopicStats
from palpa.node.endpoints import Publisher, Timer
from palpa.node.naming import RUNTIME_PREFIX
from palpa.node.nodeapi import NodeApi
from palpa.node.receive import Receiver
from palpa.runtime_msgs import CLOCK_ACK_TOPIC, CLOCK_TOPIC, ClockAck, ClockTick, tick_topic
from palpa.timing.acksign import sign
from palpa.timing.clock import TopicClock

__all__ = ["EXIT_CLOCK_LOST", "SimTime", "Timers", "ack_key", "clock_max_jump_ns", "clock_timeout_ns"]

_CLOCK_ACK_TOPIC_B = CLOCK_ACK_TOPIC.encode()
_TIMER_PASSES = 100
"""Timer passes at one instant at most (a callback may start a timer due at once; a burst of them is a bug)."""
_LEAD_ACK_NS = 10_000_000  # half a lead-mode clock's default max_lead_s: fewer acks, same bound
_SIM_CLOCK_TIMEOUT_S = 30.0
"""Wall seconds without a clock tick after which a sim-clock node stops (PALPA_SIM_CLOCK_TIMEOUT_S; 0: never)."""
_SIM_CLOCK_MAX_JUMP_S = 60.0
"""Simulated seconds a tick may move time forward at once (PALPA_SIM_CLOCK_MAX_JUMP_S; 0: no bound). The lockstep
clock moves an idle node's time by at most about ``time_scale`` seconds per wall second (its broadcast), a busy
one's from deadline to deadline; an hour ahead past a node's timers is a forged or broken tick, which would move every
timer of the graph an hour on (and a simulated driver would try to produce an hour of samples at once). A jump that
passes none of the node's timers (its own next deadline is that far, or it has none) is not bounded."""
EXIT_CLOCK_LOST = 3
"""The exit code of a sim-clock node that stopped because simulated time stopped."""


def clock_timeout_ns(timeout_s: float | None) -> int:
    """Wall ns without a clock tick after which a sim-clock node stops (0: never); None reads
    ``PALPA_SIM_CLOCK_TIMEOUT_S`` (default 30 s)."""
    return _seconds_ns(timeout_s, palpa_env.SIM_CLOCK_TIMEOUT_S, _SIM_CLOCK_TIMEOUT_S)


def clock_max_jump_ns(max_jump_s: float | None = None) -> int:
    """Simulated ns a tick may move a node's time forward at once (0: no bound); None reads
    ``PALPA_SIM_CLOCK_MAX_JUMP_S`` (default 60 s)."""
    return _seconds_ns(max_jump_s, palpa_env.SIM_CLOCK_MAX_JUMP_S, _SIM_CLOCK_MAX_JUMP_S)


def ack_key(node: str) -> bytes:
    """The key the launcher gave this process to sign ``node``'s clock acks (``PALPA_CLOCK_KEY``, hex), when it
    started ``node`` (``PALPA_NODE_NAME``); empty otherwise (another node of the process signs nothing)."""
    text = palpa_env.get(palpa_env.CLOCK_KEY)
    if not text or palpa_env.get(palpa_env.NODE_NAME) != node:
        return b""
    try:
        return bytes.fromhex(text)
    except ValueError:
        raise PalpaError(f"{palpa_env.CLOCK_KEY}: expected hex digits") from None


def _seconds_ns(given_s: float | None, variable: str, default_s: float) -> int:
    """``given_s`` in ns; None: the environment ``variable``'s seconds (``default_s`` when unset), which must be
    finite and >= 0 (0: off)."""
    if given_s is not None:
        return int(given_s * 1e9)
    text = palpa_env.get(variable)
    try:
        seconds = float(text) if text else default_s
    except ValueError:
        raise PalpaError(f"{variable}={text!r}: expected seconds") from None
    if not 0 <= seconds < float("inf"):
        raise PalpaError(f"{variable}={text!r}: expected seconds >= 0 (0: off)")
    return int(seconds * 1e9)


class Timers:
    """A node's timers (made by ``Node.timer``), run through the node's dispatch at the times they are due."""

    def __init__(self, node: NodeApi) -> None:
        self._node = node
        self._timers: list[Timer] = []

    def __len__(self) -> int:
        """Timers not yet dropped (a cancelled one goes at the next pass)."""
        return len(self._timers)

    def add(self, period_s: float, callback: Callable[[], object], oneshot: bool, first_in_s: float | None) -> Timer:
        """``Node.timer``: a timer every ``period_s`` of the node's clock from now, first after ``first_in_s``
        (None: one period)."""
        if period_s <= 0:
            raise ValueError(f"timer period must be > 0 s, got {period_s}")
        period_ns = int(period_s * 1e9)
        first = period_ns if first_in_s is None else int(first_in_s * 1e9)
        timer = Timer(period_ns, callback, self._node.clock.now_ns() + first, oneshot)
        self._timers.append(timer)
        return timer

    def next_due_ns(self) -> int | None:
        """When the earliest live timer fires, or None."""
        best = None
        for t in self._timers:  # an executor asks every node at every instant: no list, no min()
            if not t.cancelled and (best is None or t.due_ns < best):
                best = t.due_ns
        return best

    def shift(self, ns: int) -> None:
        """Move every timer ``ns`` later (timers declared before simulated time existed count from its first
        tick)."""
        for t in self._timers:
            t.due_ns += ns

    def run(self, now: int) -> None:
        """Run the timers due at ``now``, again while a callback started one due at once (at most
        ``_TIMER_PASSES`` times), until none is due or the node is shutting down."""
        for _ in range(_TIMER_PASSES):
            if not self._pass(now) or self._node.is_shutdown or \
                    not any(t.due_ns <= now and not t.cancelled and not t.running for t in self._timers):
                return

    def _pass(self, now: int) -> bool:
        """Run the timers due at ``now`` once each; whether any ran."""
        for t in self._timers:  # most passes find nothing to do: look before copying the list
            if t.due_ns <= now or t.cancelled:
                break
        else:
            return False
        ran = False
        for t in list(self._timers):
            if t.cancelled:
                if t in self._timers:  # a nested run (inside a service call's wait) may have removed it
                    self._timers.remove(t)
                continue
            if t.due_ns <= now and not t.running:  # never re-entered while it waits on a service call
                if t.oneshot:
                    t.cancelled = True
                else:
                    # skip missed periods rather than firing a burst after a stall
                    t.due_ns += t.period_ns * max(1, (now - t.due_ns) // t.period_ns + 1)
                t.running = True
                self._node.dispatch.call(t.callback)  # never raises
                t.running = False
                ran = True
        return ran


class _Host(NodeApi, Protocol):
    """What :class:`SimTime` uses of its node beyond :class:`palpa.node.nodeapi.NodeApi`."""

    incarnation: int

    def run_timers(self) -> None: ...

    def next_timer_due_ns(self) -> int | None: ...

    def request_shutdown(self, exit_code: int | None = None) -> None: ...

    def subscribe(self, topic: str, type_or_callback: Any, callback: Any = None, *, queue_size: int = 1000) -> object:
        ...


class SimTime:
    """A node's side of a simulation clock: it takes the clock's ticks (:meth:`on_clock`) and the instants of the
    messages it handles (:meth:`on_instant`), and acks to a lockstep clock what it did at each simulated time
    (:meth:`report`). ``pubs``, ``raw_sent`` and ``rx`` are the node's own: what it sent and took in."""

    def __init__(self, node: _Host, clock: TopicClock, timers: Timers, rx: Receiver,
                 pubs: Mapping[str, Publisher[Any]], raw_sent: Mapping[str, int], timeout_ns: int,
                 max_jump_ns: int | None = None) -> None:
        self._node = node
        self._max_jump_ns = clock_max_jump_ns() if max_jump_ns is None else max_jump_ns
        self.refused_jumps = 0
        """Ticks and message instants refused for moving time forward by more than the bound (``max_jump_ns``)."""
        self._clock = clock
        transport = node.transport
        # straight to the clock (palpa.net.direct): one ZeroMQ hop instead of two, at every instant of a lockstep
        ack_pub = self._ack_pub = node.publisher(CLOCK_ACK_TOPIC, ClockAck, batch=1,
                                                 direct=isinstance(transport, ZmqTransport))
        self._timers = timers
        self._rx = rx
        self._pubs = pubs
        self._raw_sent = raw_sent
        self._timeout_ns = timeout_ns
        self._last_tick_wall_ns = 0
        self._time_held = False
        """The clock holds time (a tick with ``hold``): no timer runs until it lets go."""
        self._lead_acks = False
        self._ack_heard = not ack_pub.direct
        """Whether acks reach the clock: a direct one only once the clock has connected and subscribed (what a
        direct socket sends before that is lost, and the clock would wait for it for good)."""
        self._last_ack_ns = 0
        self._acked: tuple[int, int, int, tuple[int, ...], int, int] | None = None
        self._ack_shape: tuple[int, ...] = ()
        self._ack_pubs: list[Publisher[Any]] = []
        self._ack_stats: list[tuple[str, TopicStats]] = []
        self._ack_subs: list[str] = []
        self._joins: dict[str, None] = transport.joins_heard if isinstance(transport, ZmqTransport) else {}
        self._joins_acked = 0
        self._reached: dict[str, None] = transport.reach.reached if isinstance(transport, ZmqTransport) else {}
        self._reached_acked = 0
        self._ack_direct: list[str] = []
        self._key = ack_key(node.name)
        """This node's key to sign its acks (palpa.timing.acksign; empty: its launcher gave it none)."""
        node.subscribe(CLOCK_TOPIC, ClockTick, self.on_clock)
        node.subscribe(tick_topic(node.name), ClockTick, self.on_clock)  # the event lockstep's, to this node alone
        rx.on_instant = self.on_instant

    @property
    def holds_timers(self) -> bool:
        """No timer may run: simulated time has not started, or the clock holds it."""
        return self._time_held or not self._clock.started

    def await_first_tick(self, timeout_s: float) -> None:
        """Simulated time does not exist before the first tick: wait for it (bounded) so that setup() and
        everything after it reads a real time."""
        deadline = time.monotonic() + timeout_s
        clock = self._clock
        while not clock.started and time.monotonic() < deadline:
            self._node.spin_once(0.05)
        if not clock.started and timeout_s > 0:
            self._node.log.warning("no simulation time on %s after %.0f s; timers wait for the first tick",
                                   CLOCK_TOPIC, timeout_s)

    def _refused(self, sim_ns: int, what: str) -> bool:
        """Whether moving time to ``sim_ns`` is a jump past the bound that would pass one of this node's timers
        (logged, the first time and every 1000th, and counted in :attr:`refused_jumps`): the node's time stays where
        it is. A jump that passes none of its timers is what the event lockstep gives a node whose next timer is far
        off (a 2-minute timer is ticked 2 minutes on) or that has none: taken, whatever its size. The bound is
        against a forged instant firing or skipping a node's timers at once (and the simulated drivers rendering
        the hour it skipped), which only a timer due before the new instant can do."""
        clock = self._clock
        if not (clock.started and self._max_jump_ns and sim_ns - clock.now_ns() > self._max_jump_ns):
            return False
        due = self._timers.next_due_ns()
        if due is None or due >= sim_ns:
            return False
        self.refused_jumps += 1
        self._node.refusals["clock_jump"] = self.refused_jumps
        if self.refused_jumps % 1000 == 1:
            self._node.log.error("%s at %.3f s of simulated time refused: %.0f s ahead of this node's %.3f s, more "
                                 "than the %g s a tick may jump (%s); %d refused so far", what, sim_ns / 1e9,
                                 (sim_ns - clock.now_ns()) / 1e9, clock.now_ns() / 1e9, self._max_jump_ns / 1e9,
                                 palpa_env.SIM_CLOCK_MAX_JUMP_S, self.refused_jumps)
        return True

    def on_clock(self, tick: ClockTick) -> None:
        if self._refused(tick.sim_ns, f"a tick on {CLOCK_TOPIC}"):
            return  # not a sign of life either: a clock that only jumps is a dead clock (check_alive)
        clock = self._clock
        if not clock.started:
            # timers declared before time existed count from the first tick
            self._timers.shift(tick.sim_ns)
        clock.update(tick.sim_ns)
        self._last_tick_wall_ns = time.monotonic_ns()
        self._time_held = tick.hold
        self._lead_acks = tick.lead
        # the timers due now run before any message that follows the tick is handled, as in a composition
        # (palpa.timing.compose): what another node published at this time, in reaction to the same tick, comes after
        self._node.run_timers()

    def on_instant(self, at: int) -> None:
        """A message sent at simulated instant ``at``: the event lockstep ticks a node only at its own timers'
        deadlines (palpa.timing.simclock), so it learns any other instant from the messages it handles there (timers due
        by then run first, as at a tick). Not under a lead-mode clock, whose ticks every node gets."""
        clock = self._clock
        if at > clock.now_ns() and clock.started and not self._time_held and not self._lead_acks and \
                not self._refused(at, "a message's instant"):
            clock.update(at)
            self._last_tick_wall_ns = time.monotonic_ns()
            self._node.run_timers()

    def check_alive(self) -> None:
        """Stop the node when no tick came for the timeout (wall clock): sim-time timers (watchdogs included) stop
        with the clock, so only the wall clock can tell."""
        if self._clock.started and self._timeout_ns and \
                time.monotonic_ns() - self._last_tick_wall_ns > self._timeout_ns and not self._node.is_shutdown:
            self._node.log.error("simulated time stopped: no tick on %s for %.1f s of wall time (did the clock node "
                                 "die?); stopping", CLOCK_TOPIC, self._timeout_ns / 1e9)
            self._node.request_shutdown(EXIT_CLOCK_LOST)

    def report(self, probe: str) -> None:
        """Ack to the clock when there is something new to say and the node is between callbacks (``probe``: the
        node's confirmed readiness probe, see :class:`palpa.runtime_msgs.ClockAck`)."""
        clock = self._clock
        node = self._node
        if clock.started and not node.dispatch.depth and not node.closed:
            if not self._ack_heard:
                t = node.transport
                if isinstance(t, ZmqTransport) and not t.subscribed_exactly(_CLOCK_ACK_TOPIC_B):
                    return  # the clock's subscription arriving on the direct socket wakes this node's poll
                self._ack_heard = True
            if self._lead_acks and clock.now_ns() - self._last_ack_ns >= _LEAD_ACK_NS:
                self._acked = None  # a lead-mode clock holds time within a lead of this ack: send one anyway
            self._ack(probe)

    def _ack(self, probe: str) -> None:
        """Tell the lockstep clock (palpa.timing.simclock) what this node has done at the current simulated time, when
        that changed: its next timer, and the messages it sent and took in (the clock moves on once every message
        sent has been taken in). Not from inside a callback: a node waiting in a service call is not done."""
        self._node.flush()
        rx = self._rx
        shape = (len(self._pubs), len(rx.subs), len(rx.raw), len(rx.raw_stats))
        if shape != self._ack_shape:  # what is counted changes rarely: list it once per change
            self._ack_shape = shape
            self._ack_pubs = [p for p in self._pubs.values() if not p.topic.startswith(RUNTIME_PREFIX)]
            self._ack_stats = [(t, st) for t, st in rx.counters().items() if not t.startswith(RUNTIME_PREFIX)]
            self._ack_subs = [s.topic for s in rx.subs.values() if not s.topic.startswith(RUNTIME_PREFIX)]
            self._ack_subs += [r.prefix.decode(errors="replace") + "*" for r in rx.raw
                               if not r.prefix.startswith(RUNTIME_PREFIX.encode())]
            self._ack_direct = [p.topic for p in self._ack_pubs if p.direct]
        due = self._node.next_timer_due_ns() or 0
        sent_total = sum(p.seq for p in self._ack_pubs) + sum(self._raw_sent.values())
        recv_total = sum(st.received + st.decode_errors for _, st in self._ack_stats)
        heard, reached = len(self._joins), len(self._reached)
        state = (due, sent_total, recv_total, shape, heard, reached)
        if state == self._acked:
            return
        self._acked = state
        new_joins = list(self._joins)[self._joins_acked:] if heard > self._joins_acked else []
        self._joins_acked = heard
        new_reached = list(self._reached)[self._reached_acked:] if reached > self._reached_acked else []
        self._reached_acked = reached
        direct = self._ack_direct
        t = self._node.transport
        sent = {p.topic: p.seq for p in self._ack_pubs if p.seq}
        for topic, n in self._raw_sent.items():
            sent[topic] = sent.get(topic, 0) + n
        self._last_ack_ns = self._clock.now_ns()
        self._send(ClockAck(node=self._node.name, sim_ns=self._last_ack_ns, next_ns=due, sent=sent,
                            recv={t: st.received + st.decode_errors for t, st in self._ack_stats},
                            subs=self._ack_subs, probe=probe, heard=new_joins, direct=direct,
                            direct_at=t.direct_endpoint if direct and isinstance(t, ZmqTransport) else "",
                            reached=new_reached))

    def leave(self) -> None:
        """Tell the lockstep clock that this node is leaving: it stops waiting for it now, not later."""
        self._send(ClockAck(node=self._node.name, sim_ns=self._last_ack_ns, leaving=True))

    def _send(self, ack: ClockAck) -> None:
        """Publish ``ack``, signed with this node's key when it has one (as the message number it goes out as)."""
        if self._key:
            ack = msgspec.structs.replace(ack, mac=sign(self._key, ack, self._node.incarnation,
                                                        self._ack_pub.seq + 1))
        self._ack_pub.publish(ack)
