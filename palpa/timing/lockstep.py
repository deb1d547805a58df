"""The bookkeeping of the event lockstep: when may simulated time move on, and to when.

A composition (:mod:`palpa.timing.compose`) runs its nodes' timers due at an instant, lets every message published in
reaction be handled (and every message those published...), and only then jumps to the next timer deadline. The
lockstep clock (:mod:`palpa.timing.simclock`) gives processes the same timeline, from what each sim-clock node reports
in its :class:`~palpa.runtime_msgs.ClockAck`: its next timer deadline, and per topic the messages it has sent and
taken in. Time moves from ``now`` only when

* no node has a timer due at or before ``now`` that it has not run (its ack names a later deadline), and
* every participant is heard: a node whose subscriptions a readiness probe confirmed (palpa.node.presence) counts as a
  subscriber only once every other participant's publisher socket has heard that probe (ClockAck ``heard``), so
  that no message is dropped on its way to it for want of a route; until then time waits, and its accounting
  starts when the last one heard it; likewise a subscriber of a topic another participant publishes direct
  (palpa.net.direct) counts on that publisher only once it reports that the publisher's direct socket answered its
  probe (ClockAck ``reached``, palpa.net.reach), and its accounting of that publisher's direct topics starts then;
* nothing is in flight: for every topic, each subscriber has taken in at least as many messages as its
  publishers sent since the subscriber's accounting started (its join, or the start of time: messages published
  before a subscriber was there never reach it);

and then to the earliest deadline any node reported. The order in which messages of one instant arrive is then the
only thing that can differ from a composed run; no node reads the wall clock for what it computes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from palpa.runtime_msgs import ClockAck

__all__ = ["EventLockstep", "InFlight"]


@dataclass
class _Member:
    ack: ClockAck
    exact: frozenset[str] = frozenset()
    prefixes: tuple[str, ...] = ()
    takes: dict[str, bool] = field(default_factory=dict)
    """Topic -> whether this member subscribes to it (a cache of ``exact``/``prefixes``)."""
    base_recv: dict[str, int] = field(default_factory=dict)
    """Its ``recv`` when its accounting started."""
    base: dict[str, int] = field(default_factory=dict)
    """Per topic, the messages sent that this member is not expected to take in (sent before its accounting
    started, or by a publisher before that one joined)."""
    heard: set[str] = field(default_factory=set)
    """The readiness probes this member's publisher socket has heard (ClockAck ``heard``, accumulated)."""
    reached: set[str] = field(default_factory=set)
    """The direct endpoints that answered this member's direct probes (ClockAck ``reached``, accumulated)."""
    owed: dict[str, int] = field(default_factory=dict)
    """Per topic it subscribes to, the messages sent to it that it has not taken in (yet): kept up to date report
    by report, so that asking whether anything is in flight costs nothing at each of the thousands of instants."""

    def subscribe(self, subs: list[str]) -> None:
        self.exact = frozenset(s for s in subs if not s.endswith("*"))
        self.prefixes = tuple(s[:-1] for s in subs if s.endswith("*"))
        self.takes = {}

    def wants(self, topic: str) -> bool:
        hit = self.takes.get(topic)
        if hit is None:
            hit = self.takes[topic] = topic in self.exact or any(topic.startswith(p) for p in self.prefixes)
        return hit


@dataclass(frozen=True)
class InFlight:
    """Messages sent on ``topic`` that ``subscriber`` has not taken in (yet): ``missing`` of them."""

    topic: str
    subscriber: str
    missing: int


class EventLockstep:
    """The participants' latest reports (event acks only: ``next_ns >= 0``) and the rules above."""

    def __init__(self) -> None:
        self.members: dict[str, _Member] = {}
        self._unheard: set[str] = set()
        """Members whose probe some other member has not reported hearing yet."""
        self._sent: dict[str, int] = {}
        """Per topic, the messages the participants sent (their latest reports summed, those who left included:
        what a node sent before it left is still on its way)."""
        self._takers: dict[str, list[_Member]] = {}
        self._short: dict[tuple[str, str], None] = {}
        """(member, topic) pairs with messages in flight, oldest first (a dict: an ordered set)."""
        self._unreached: list[tuple[str, str]] = []
        """(subscriber, direct publisher) pairs where the subscriber has not reported reaching the publisher."""
        self._reach_dirty = False

    def __contains__(self, node: str) -> bool:
        return node in self.members

    def report(self, ack: ClockAck) -> bool:
        """Take a node's latest report; True when it is a new participant (its accounting starts now)."""
        member = self.members.get(ack.node)
        if member is not None:
            old = member.ack
            member.ack = ack
            resubscribed = ack.subs != old.subs
            if resubscribed:
                member.subscribe(ack.subs)
                self._takers.clear()
            if ack.sent != old.sent:
                for topic, n in ack.sent.items():
                    if d := n - old.sent.get(topic, 0):
                        self._sent[topic] = self._sent.get(topic, 0) + d
                        for taker in self._taking(topic):
                            self._owe(taker, topic, d)
            if resubscribed:
                self._recount(member)
            elif ack.recv != old.recv:
                for topic, n in ack.recv.items():
                    if (d := n - old.recv.get(topic, 0)) and member.wants(topic):
                        self._owe(member, topic, -d)
            if resubscribed or ack.reached or ack.direct_at != old.direct_at or ack.direct != old.direct:
                member.reached.update(ack.reached)
                self._reach_dirty = True
                self._check_reach()
            if ack.heard:
                member.heard.update(ack.heard)
                self._confirm()
            return False
        member = self.members[ack.node] = _Member(ack, heard=set(ack.heard), reached=set(ack.reached))
        self._reach_dirty = True
        member.subscribe(ack.subs)
        self._takers.clear()
        _add(self._sent, ack.sent)
        for other in self.members.values():
            if other is not member:  # what it sent before joining (or rejoining) reached no one we count
                _add(other.base, ack.sent)
        self._start(member)
        if ack.probe:
            self._unheard.add(ack.node)
        self._confirm()
        self._check_reach()
        return True

    def probe(self, node: str) -> str:
        """The readiness probe ``node`` reported ("": none)."""
        return self.members[node].ack.probe

    def unheard(self) -> tuple[str, str] | None:
        """A participant (first) whose probe another one (second) has not reported hearing; None: all heard."""
        for name in self._unheard:
            probe = self.members[name].ack.probe
            for other, m in self.members.items():
                if other != name and m.ack.probe and probe not in m.heard:
                    return name, other
        return self._unreached[0] if self._unreached else None

    def assume_heard(self) -> None:
        """Stop waiting for the participants' probes to be heard and their direct publishers to be reached (the
        clock's stall timeout)."""
        for name in self._unheard:
            self._start(self.members[name])
        self._unheard.clear()
        for sub, pub in self._unreached:
            self.members[sub].reached.add(self.members[pub].ack.direct_at)
        self._reach_dirty = True
        self._check_reach()

    def _check_reach(self) -> None:
        """Which subscribers have not reached a participant that publishes a topic they take direct (recomputed only
        when an ack changed what it depends on); a subscriber that now has counts that publisher's direct topics from
        now: what was sent before may have found no route to it."""
        if not self._reach_dirty:
            return
        self._reach_dirty = False
        members = self.members
        unreached = [(sub, pub) for pub, p in members.items() if p.ack.direct_at and p.ack.direct
                     for sub, m in members.items() if sub != pub and p.ack.direct_at not in m.reached
                     and any(m.wants(t) for t in p.ack.direct)]
        for sub, pub in self._unreached:
            if (sub, pub) not in unreached and sub in members and pub in members:
                member = members[sub]
                for topic in members[pub].ack.direct:
                    if member.wants(topic):
                        member.base[topic] = self._sent.get(topic, 0)
                        member.base_recv[topic] = member.ack.recv.get(topic, 0)
                self._recount(member)
        self._unreached = unreached

    def _confirm(self) -> None:
        """Start the accounting of every participant whose probe all others have now heard: what was sent to it
        before may have found no route."""
        if not self._unheard:
            return
        for name in list(self._unheard):
            probe = self.members[name].ack.probe
            if all(probe in m.heard for other, m in self.members.items() if other != name and m.ack.probe):
                self._unheard.discard(name)
                self._start(self.members[name])

    def restart_accounting(self) -> None:
        """Count from now for everyone (when time starts: what was published while setting up is not waited for)."""
        for member in self.members.values():
            self._start(member)

    def leave(self, node: str) -> None:
        """``node`` no longer takes part: its timers and what it should take in are no longer waited for (what it
        sent still is: a node leaving in order flushed it; one whose process died may have lost it, and the
        clock's stall timeout covers that)."""
        member = self.members.pop(node, None)
        if member is not None:
            self._clear_owed(member)
            self._takers.clear()
        self._unheard.discard(node)
        self._confirm()
        self._reach_dirty = True
        self._check_reach()

    def due(self, now_ns: int) -> list[str]:
        """Participants with a timer due at or before ``now_ns`` that they have not reported running."""
        return [name for name, m in self.members.items() if 0 < m.ack.next_ns <= now_ns]

    def next_event_ns(self) -> int | None:
        """The earliest timer deadline any participant reported (None: no participant has a timer)."""
        dues = [m.ack.next_ns for m in self.members.values() if m.ack.next_ns > 0]
        return min(dues) if dues else None

    def in_flight(self) -> InFlight | None:
        """A topic on which some subscriber has not taken in everything sent to it (None: nothing in flight)."""
        for name, topic in self._short:
            return InFlight(topic, name, self.members[name].owed[topic])
        return None

    def _taking(self, topic: str) -> list[_Member]:
        """The members subscribed to ``topic`` (cached until someone joins, leaves or subscribes anew)."""
        takers = self._takers.get(topic)
        if takers is None:
            takers = self._takers[topic] = [m for m in self.members.values() if m.wants(topic)]
        return takers

    def _owe(self, member: _Member, topic: str, d: int) -> None:
        owed = member.owed[topic] = member.owed.get(topic, 0) + d
        if owed > 0:
            self._short[(member.ack.node, topic)] = None
        else:
            self._short.pop((member.ack.node, topic), None)

    def _clear_owed(self, member: _Member) -> None:
        for topic in member.owed:
            self._short.pop((member.ack.node, topic), None)
        member.owed = {}

    def _recount(self, member: _Member) -> None:
        """Its debts from scratch (its subscriptions changed): sent since its start less taken in since."""
        self._clear_owed(member)
        base, recv, base_recv = member.base, member.ack.recv, member.base_recv
        for topic, n in self._sent.items():
            if member.wants(topic):
                self._owe(member, topic, (n - base.get(topic, 0)) - (recv.get(topic, 0) - base_recv.get(topic, 0)))

    def _start(self, member: _Member) -> None:
        member.base_recv = dict(member.ack.recv)
        member.base = dict(self._sent)
        self._clear_owed(member)


def _add(into: dict[str, int], counts: dict[str, int]) -> None:
    for topic, n in counts.items():
        into[topic] = into.get(topic, 0) + n
