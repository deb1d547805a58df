"""Simulation time for a whole graph: a node that publishes ``ClockTick`` on ``_palpa/clock``.

Nodes started with ``--sim-clock`` (or ``PALPA_SIM_CLOCK=1`` in their environment) take their time from it, so a
simulated graph can run ``time_scale`` times faster than real time and still stamp, time out and rate-limit
consistently. ``palpa play --clock`` drives the same topic from a recording.

Event lockstep: every sim-clock node reports on ``_palpa/lockstep`` its next timer deadline and the messages it
has sent and taken in (:class:`~palpa.runtime_msgs.ClockAck`); the source moves time to the earliest deadline only
once no timer is left due and no message is in flight (:mod:`palpa.timing.lockstep`), so the graph sees the timeline a
composition (:mod:`palpa.timing.compose`) gives it: timers at their exact deadlines, every message handled at the
instant it was sent. Each instant goes only to the nodes with a timer due at it, each on its own topic
(``_palpa/tick/<node>/``; ticks and acks go straight between clock and node, palpa.net.direct, not through the
proxy); the others take it from the messages they handle (``Header.at``), and ``_palpa/clock``
carries the held start, the release and, once a wall second, the current time. Time starts only when every node
named in ``participants`` (the launcher fills in the file's sim-clock nodes) has set up: until then the source
publishes the start time with ``hold``. Time never runs faster than ``time_scale`` (a ceiling); on an overloaded
machine it slows down instead. A client that acks without a deadline (``next_ns`` -1) is kept within
``max_lead_s`` of the time it acked, as before events.

Who participates: a node is in from its first ack until it *leaves*, never because it is slow. A CPU-starved node
may not ack for seconds; dropping it then lets time run on without it, and its peers' sim-time watchdogs trip on
its stale data. So a node leaves only

* by saying so: its last ack, sent as it closes (a clean shutdown, a crash that still runs ``close``), carries
  ``leaving``;
* when its process is gone: the node's heartbeats name its pid and host; for a node on this host whose pid no
  longer exists (checked once it has been silent for ``check_after_s``), the clock stops waiting at once;
* when nothing at all (ack or heartbeat) has come from it for ``participant_timeout_s`` and its process cannot be
  checked (another host, or no heartbeat heard). A node on this host whose process is alive holds time however
  long it is silent (a warning says so once).

A node that acks again after it was dropped takes part again.

Which acks count: only those bound to the identity of the node they report on, its name and incarnation, in order,
for a time already issued (:mod:`palpa.timing.ackgate`); the others are refused, counted in the clock's ``refusals``
(``palpa node info``) and logged at a rate limit, so no client of the bus can move time past a node or freeze it
with acks of its own making.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Callable, Mapping
from typing import Any, Literal

from palpa import env as palpa_env
from palpa.errors import PalpaError
from palpa.lograte import LogThrottle
from palpa.net.transport import ZmqTransport
from palpa.net.wire import Header
from palpa.node.endpoints import MsgInfo
from palpa.node.node import Node, Publisher
from palpa.node.params import NonNegative, Positive
from palpa.node.params import Params as ParamsBase
from palpa.node.runner import run_node
from palpa.runtime_msgs import (
    CLOCK_ACK_TOPIC,
    CLOCK_TOPIC,
    HEARTBEAT_TOPIC,
    ClockAck,
    ClockTick,
    Heartbeat,
    tick_topic,
)
from palpa.timing.ackgate import REASONS, AckGate
from palpa.timing.acksign import node_key, verify
from palpa.timing.clock import SystemClock
from palpa.timing.lockstep import EventLockstep

__all__ = ["ClockSource"]

_REPEAT_NS = 1_000_000_000
"""Wall ns after which the current time is published again though it did not move (a held start, a slow node)."""
_CHECK_EVERY_NS = 50_000_000
"""Wall ns between looks at the event participants' silence (check_after_s is whole seconds)."""
_MAX_BURST_NS = 100_000_000
"""Wall ns of lead the ceiling keeps when the graph is slower than it (no burst past time_scale afterwards)."""


class ClockSource(Node):
    """Publishes simulation time: ``start + time_scale * (wall time since start)`` at ``rate_hz`` wall ticks."""

    class Params(ParamsBase):
        time_scale: Positive = 1.0
        """Simulated seconds per wall-clock second (> 0)."""
        rate_hz: Positive = 1000.0
        """Ticks per wall-clock second: the time resolution timers in sim-clock nodes get."""
        max_lead_s: NonNegative = 0.02
        """Simulated seconds the clock may run ahead of the slowest acknowledging node (0: no lockstep)."""
        participant_timeout_s: Positive = 30.0
        """A node whose process cannot be checked (another host) and not heard for this long (wall clock, acks or
        heartbeats) no longer holds the clock back. A live process on this host holds it however long it is silent."""
        check_after_s: Positive = 2.0
        """A node on this host silent for this long (wall clock) has its process checked: gone, it is dropped."""
        lockstep: Literal["events", "lead"] = "events"
        """``events``: the composition's timeline (module docstring). ``lead``: time runs at ``time_scale`` and only
        stays within ``max_lead_s`` of the slowest node's ack, which costs far fewer exchanges (several times faster
        on a busy machine) but lets sample phases and noise follow the machine's timing: runs differ."""
        participants: list[str] = []
        """Nodes time waits for before it starts (each joins with its first ack, after its setup)."""
        frozen_after_s: Positive = 60.0
        """Wall seconds simulated time may stand still, once started, before the launcher ends the graph as frozen
        (exit code 1; palpa.launch.clockwatch: it watches this clock from outside, where a frozen graph shows)."""
        join_timeout_s: Positive = 120.0
        """Wall seconds after which time starts without the participants that have not joined (a warning names
        them)."""

    params: Params  # typed: mypy checks every self.params.<name>

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | Params | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # the source of time cannot follow itself
        kwargs.setdefault("clock", SystemClock())
        super().__init__(name, params, **kwargs)

    def setup(self) -> None:
        if self.params.time_scale <= 0 or self.params.rate_hz <= 0:
            raise ValueError("time_scale and rate_hz must be > 0")
        self._pub = self.publisher(CLOCK_TOPIC, ClockTick, batch=1)
        self.pid_alive: Callable[[int], bool] = _pid_alive
        """Whether a process of this host exists (replaceable in tests)."""
        self._host = socket.gethostname()
        self._wall = time.monotonic_ns()
        self._sim = time.time_ns() // 1_000_000_000 * 1_000_000_000  # on a whole second, as palpa.timing.compose starts
        self._acks: dict[str, int] = {}
        """participating node -> the simulated ns it acknowledged last"""
        self._heard: dict[str, int] = {}
        """participating node -> wall monotonic ns it was last heard (an ack or a heartbeat)"""
        self._pids: dict[str, int] = {}
        """participating node -> its pid, when its heartbeats say it runs on this host"""
        self._held: set[str] = set()
        self._events = EventLockstep()
        master = palpa_env.get(palpa_env.CLOCK_MASTER_KEY)
        try:
            key = bytes.fromhex(master)
        except ValueError:
            raise PalpaError(f"{palpa_env.CLOCK_MASTER_KEY}: expected hex digits") from None
        # signatures are checked for the launch's participants when the launcher gave this clock its run's key
        keys = {n: node_key(key, n) for n in self.params.participants}
        self._gate = AckGate(frozenset(keys), (lambda ack, h: verify(keys[ack.node], ack, h.inc, h.seq)) if key else None)
        self._throttle = LogThrottle(self.log, now=lambda: self.clock.now_ns() / 1e9)
        self._waiting: list[tuple[ClockAck, Header]] = []
        """Acks the gate let through again (their name free, their node heard), to be taken next."""
        self._started_wall = self._wall
        self._released = not self.params.participants
        self._anchor = (self._wall, self._sim)
        """(wall, simulated) ns the time_scale ceiling counts from."""
        self._last_pub_wall = 0
        """Wall ns of the last broadcast on _palpa/clock."""
        self._tick_pubs: dict[str, tuple[Publisher[ClockTick], bytes]] = {}
        self._checked_wall = 0
        self._stalled_since = 0
        if self.params.max_lead_s > 0:
            self.subscribe(CLOCK_ACK_TOPIC, self._on_ack)
            self.subscribe(HEARTBEAT_TOPIC, self._on_heartbeat)
        self.timer(1.0 / self.params.rate_hz, self._tick, first_in_s=0.0)

    def _on_ack(self, ack: ClockAck, info: MsgInfo) -> None:
        self._believe(ack, info.header)
        self._admit_waiting()

    def _admit_waiting(self) -> None:
        """Check again the acks kept waiting for their name to be free or their node to be heard (not from inside
        :meth:`_advance`, which may free a name)."""
        while self._waiting:
            self._believe(*self._waiting.pop(0))

    def _believe(self, ack: ClockAck, header: Header) -> None:
        """An ack, believed only when bound to its node's identity (palpa.timing.ackgate); a refusal is counted
        (``refused`` in the clock's heartbeats: ``palpa node info``) and logged, one line per kind and interval."""
        why = self._gate.check(ack, header, self._sim)
        if why is not None:
            key = f"clock_ack/{why}"
            self.refusals[key] = self._gate.refused[why]  # the gate counts; the heartbeat shows its count
            self._throttle.event(key, logging.WARNING, "ack for %s refused (%d so far): %s (from %s, incarnation "
                                 "%d, seq %d, at %.3f s; the clock is at %.3f s)", ack.node[:80], self.refusals[key],
                                 REASONS[why], header.node[:80], header.inc, header.seq,
                                 ack.sim_ns / 1e9, self._sim / 1e9)
            return
        if ack.leaving:
            self._events.leave(ack.node)
            if self._acks.pop(ack.node, None) is not None:
                self.log.info("%s left: it no longer holds simulated time back", ack.node)
            self._released_name(ack.node)
            self._advance()
            return
        self._acks[ack.node] = ack.sim_ns
        self._heard[ack.node] = time.monotonic_ns()
        self._held.discard(ack.node)
        if ack.next_ns >= 0 and self.params.lockstep == "events":
            if self._events.report(ack):
                self._tick_pub(ack.node)  # announced now: the node connects before its first tick
                if self._released:
                    self.log.info("%s joined at %.3f s of simulated time", ack.node, ack.sim_ns / 1e9)
            self._advance()
        elif not self._released:
            self._advance()

    def _on_heartbeat(self, hb: Heartbeat, info: MsgInfo) -> None:
        inc = info.header.inc
        if hb.node in self._acks and self._gate.owns(hb.node, inc):
            # only participants (every node heartbeats, few follow the clock), and only the incarnation that takes
            # part: another process under its name does not keep it alive
            self._heard[hb.node] = time.monotonic_ns()
            if hb.host == self._host:
                self._pids[hb.node] = hb.pid
            else:
                self._pids.pop(hb.node, None)
        elif (waiting := self._gate.heard(hb.node, inc)) is not None:
            self._waiting.append(waiting)  # a node from outside the launch file, present now: its last ack counts
            self._admit_waiting()

    def _released_name(self, node: str) -> None:
        """``node``'s incarnation no longer takes part: an ack another incarnation sent under its name meanwhile
        (a respawned node) counts now."""
        self._pids.pop(node, None)
        waiting = self._gate.release(node)
        if waiting is not None:
            self._waiting.append(waiting)

    def _still_in(self, node: str, wall: int) -> bool:
        """Whether ``node`` still holds simulated time back (see the module's docstring); says a drop once."""
        silent_s = (wall - self._heard.get(node, wall)) / 1e9
        if silent_s < self.params.check_after_s:
            return True
        pid = self._pids.get(node)
        if pid is not None:
            if self.pid_alive(pid):
                if silent_s >= self.params.participant_timeout_s and node not in self._held:
                    self._held.add(node)
                    self.log.warning("%s (pid %d) not heard for %.0f s (wall clock) but alive: simulated time waits "
                                     "for it", node, pid, silent_s)
                return True
            why = f"its process (pid {pid}) is gone"
        elif silent_s < self.params.participant_timeout_s:
            return True
        else:
            why = f"not heard for {self.params.participant_timeout_s:.1f} s (wall clock)"
        self._acks.pop(node)
        self._events.leave(node)
        self.log.warning("%s %s: it no longer holds simulated time back", node, why)
        self._released_name(node)
        return False

    def sim_now_ns(self) -> int:
        """Advance simulated time by the wall time since the last call (scaled), held back to the lockstep limit."""
        wall = time.monotonic_ns()
        proposed = self._sim + int((wall - self._wall) * self.params.time_scale)
        self._wall = wall
        live = [sim for node, sim in list(self._acks.items()) if self._still_in(node, wall)]
        if live and self.params.max_lead_s > 0:
            limit = min(live) + int(self.params.max_lead_s * 1e9)
            if proposed > limit:
                proposed = max(limit, self._sim)
        self._sim = proposed
        return proposed

    def _tick(self) -> None:
        self._admit_waiting()
        if not self._released or self._events.members:
            self._advance()
            wall = time.monotonic_ns()
            if wall - self._last_pub_wall > _REPEAT_NS:  # nodes guard against a dead clock on the wall clock
                self._publish(self._sim, wall)
            return
        self._publish(self.sim_now_ns(), time.monotonic_ns())

    def _publish(self, sim_ns: int, wall: int) -> None:
        self._last_pub_wall = wall
        self._pub.publish(ClockTick(sim_ns=sim_ns, hold=not self._released, lead=self.params.lockstep == "lead"))

    def _advance(self) -> None:
        """Event lockstep (module docstring): start time once the participants joined; then move it to the next
        deadline when nothing is due or in flight and the time_scale ceiling allows."""
        wall = time.monotonic_ns()
        if not self._released:
            missing = [n for n in self.params.participants if n not in self._events and n not in self._acks]
            unheard = self._events.unheard()
            if (missing or unheard) and (wall - self._started_wall) / 1e9 < self.params.join_timeout_s:
                return
            if missing:
                self.log.warning("%s not joined after %.0f s (wall clock): simulated time starts without them",
                                 ", ".join(missing), self.params.join_timeout_s)
            if unheard:
                self.log.warning("%s's subscriptions not heard by %s after %.0f s (wall clock): simulated time "
                                 "starts anyway", *unheard, self.params.join_timeout_s)
            self._released = True
            self._events.restart_accounting()
            self._anchor = (wall, self._sim)
            self._wall = wall  # a lead-mode clock counts from the start, not from its own setup
            self._publish(self._sim, wall)
            return
        if not self._events.members:
            return  # no event participant (yet, or any more): _tick runs time on the wall clock
        if wall - self._checked_wall > _CHECK_EVERY_NS:  # silence is judged in seconds: not at every instant
            self._checked_wall = wall
            for node in [n for n in self._events.members if n in self._acks]:
                self._still_in(node, wall)
        now = self._sim
        if self._events.due(now):
            return
        unheard = self._events.unheard()
        if unheard is not None:
            if self._stalled(wall):
                return
            self.log.warning("%s's subscriptions not heard by %s in %.0f s (wall clock): time moves on", *unheard,
                             self.params.participant_timeout_s)
            self._events.assume_heard()
        flying = self._events.in_flight()
        if flying is not None:
            if self._stalled(wall):
                return
            self.log.warning("%d message(s) on %s never reached %s in %.0f s (wall clock): time moves on",
                             flying.missing, flying.topic, flying.subscriber, self.params.participant_timeout_s)
        self._stalled_since = 0
        target = self._events.next_event_ns()
        anchor_wall, anchor_sim = self._anchor
        ceiling = anchor_sim + int((wall - anchor_wall) * self.params.time_scale)
        if ceiling - now > _MAX_BURST_NS * self.params.time_scale:  # slower than the ceiling: no catching up later
            self._anchor = (wall - _MAX_BURST_NS, now)
            ceiling = now + int(_MAX_BURST_NS * self.params.time_scale)
        if target is None:
            target = ceiling  # no timer anywhere: time runs at the ceiling
        elif target > ceiling:
            return  # the wall-clock tick comes back to it
        legacy = [sim for node, sim in self._acks.items() if node not in self._events]
        if legacy and self.params.max_lead_s > 0:
            target = min(target, max(now, min(legacy) + int(self.params.max_lead_s * 1e9)))
        if target > now:
            self._sim = target
            if legacy:
                self._publish(target, wall)  # a client without deadlines follows the broadcast
            else:
                self._tick_due(target)

    def _tick_due(self, sim_ns: int) -> None:
        """Send the new instant to the participants with a timer due at it, each on its own topic: the others learn
        it from the messages they handle at it (``Header.at``, palpa.node.node_time), so a node with nothing to do at an
        instant is not woken (the broadcast every second keeps idle nodes' watchdogs fed)."""
        pubs = [self._tick_pub(n) for n in self._events.due(sim_ns)]
        t = self.transport
        if isinstance(t, ZmqTransport) and not all(t.subscribed_exactly(key) for _, key in pubs):
            # that node's subscription to its own topic has not reached our (direct) socket yet: a tick sent there
            # would be dropped and hold time for good; the broadcast goes through the bus, whose route to it the
            # node's readiness probe confirmed
            self._publish(sim_ns, time.monotonic_ns())
            return
        tick = ClockTick(sim_ns=sim_ns)
        for pub, _ in pubs:
            pub.publish(tick)

    def _tick_pub(self, node: str) -> tuple[Publisher[ClockTick], bytes]:
        """The publisher of ``node``'s instants, straight to it (palpa.net.direct: one ZeroMQ hop instead of two), and
        its topic as the wire has it (looked up at every instant)."""
        entry = self._tick_pubs.get(node)
        if entry is None:
            pub = self.publisher(tick_topic(node), ClockTick, batch=1, direct=isinstance(self.transport, ZmqTransport))
            entry = self._tick_pubs[node] = (pub, pub.topic.encode())
        return entry

    def _stalled(self, wall: int) -> bool:
        """Whether time still waits (for a message in flight, a participant not heard): True until it has waited
        ``participant_timeout_s`` of wall time."""
        if not self._stalled_since:
            self._stalled_since = wall
        return (wall - self._stalled_since) / 1e9 < self.params.participant_timeout_s


def _pid_alive(pid: int) -> bool:
    """A process with this pid exists on this host and has not died (a zombie, not yet reaped, has)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[-1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True  # no procfs: kill(0) said it exists


if __name__ == "__main__":
    run_node(ClockSource)
