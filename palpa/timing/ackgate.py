"""Which clock acknowledgements the lockstep clock believes: each is bound to the identity of the node it reports on.

Any client of the bus can publish on ``_palpa/lockstep``. An ack the clock believed blindly could move time past a
node that has not run its timers (a forged ``next_ns`` later than its real deadline, or a forged ``leaving``), or
freeze it (a deadline already passed, counts that never balance, a replayed old report). :class:`AckGate` lets an ack
through only when it is consistent with the node it names:

* **its sender**: the envelope's publisher (``Header.node``) is the node the ack reports on: no client acks on
  behalf of another (``palpa topic pub _palpa/lockstep``, a hand-written client under its own name); and in a
  launched graph, an ack about one of the launch's participants carries that node's signature over its name,
  incarnation, sequence number and content (palpa.timing.acksign): only the node the launcher gave that key can
  make one;
* **its incarnation**: a node name is bound to the incarnation (``Header.inc``, drawn anew at each start,
  palpa.node.presence) of its first ack believed, until that incarnation leaves (its own ``leaving`` ack) or the
  clock drops it (its process gone, or silent): acks under that name from another incarnation (a duplicate node, a
  stale process, a client copying the name) are refused; the latest of them is kept and let through once the
  binding ends, so a respawned node joins without a stall;
* **its order**: per binding the ack's sequence number (``Header.seq``) grows, by at most :data:`MAX_SEQ_STEP`, and
  its ``sim_ns`` never goes back: a duplicate, a replay or a reordering is refused;
* **its time**: ``sim_ns`` is a time the clock has issued (not after its current time; a ``leaving`` ack's time
  says nothing);
* **its presence**, in a launched graph (the clock was told its ``participants``): a node not among them is believed
  only once its heartbeats (same name and incarnation) have been heard, so an invented participant cannot hold time
  with an ack alone; its latest ack is kept until then.

Every refusal is counted by kind (:attr:`AckGate.refused`). Without the launch's key (a clock started by hand, or a
node outside the participants) the bus authenticates no node name: a client that copies a node's whole header
(name, incarnation, next sequence number: all visible on the bus) is not told apart from it, and one that acks under
a name before that node's first ack holds the name; the checks above make it race that node ack by ack, its
refusals counted and logged by the clock, rather than steer time with one message. This module is pure bookkeeping: the clock
(palpa.timing.simclock) logs and acts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from palpa.net.wire import Header
from palpa.runtime_msgs import ClockAck

__all__ = ["MAX_PENDING", "MAX_SEQ_STEP", "REASONS", "AckGate"]

MAX_SEQ_STEP = 10_000
"""How far an ack's sequence number may run ahead of its binding's last (acks are sent one per message, and more than
this many lost in a row is no clock that works: a number further on is refused)."""
MAX_PENDING = 256
"""Acks kept waiting for their node's binding to end or its heartbeats to be heard (the latest per name; the least
recently updated name is forgotten past this)."""
_MAX_PRESENT = 4096
"""Names whose heartbeat incarnation is remembered (least recently heard forgotten past this)."""
_MAX_NAMES = 4096
"""Bindings kept, those that left included (the least recently believed of those that left forgotten past this)."""

REASONS = {
    "not_sender": "sent by another node than the one it reports on",
    "bad_signature": "about one of the launch's participants, without that node's signature (palpa.timing.acksign)",
    "other_incarnation": "from another incarnation than the one that takes part under that name",
    "out_of_order": "a duplicate, replay or reordering (its sequence number or time goes back)",
    "seq_jump": f"its sequence number more than {MAX_SEQ_STEP} past the last believed",
    "not_issued": "for a time the clock has not issued yet",
    "not_present": "from a node outside the launch's participants whose heartbeats were not heard (yet)",
}
"""Refusal kind -> what it means, for logs and docs."""


@dataclass
class _Binding:
    inc: int
    seq: int
    sim_ns: int
    active: bool = True
    """False once its incarnation left or was dropped: another incarnation may take the name, and this one's next
    ack (a dropped node that acks again takes part again) must still come in order."""


class AckGate:
    """The bindings of node names to incarnations, and the checks above. ``expected``: the launch's participants
    (empty: any node may join on its first ack, as with a clock started by hand). ``verify``: whether an ack about
    one of them carries its node's signature (palpa.timing.acksign; None: a clock without the launch's key)."""

    def __init__(self, expected: frozenset[str] = frozenset(),
                 verify: Callable[[ClockAck, Header], bool] | None = None) -> None:
        self._expected = expected
        self._verify = verify
        self._bound: dict[str, _Binding] = {}
        self._present: dict[str, int] = {}
        """Name -> the incarnation its heartbeats carry (nodes outside ``expected`` only)."""
        self._pending: dict[str, tuple[ClockAck, Header]] = {}
        """Name -> its latest ack refused as ``other_incarnation`` or ``not_present``: believed once it may be."""
        self.refused: dict[str, int] = {}
        """Refused acks by kind (:data:`REASONS`)."""

    def check(self, ack: ClockAck, header: Header, now_ns: int) -> str | None:
        """Why ``ack`` (arrived with ``header``, the clock at ``now_ns``) is not believed (a :data:`REASONS` key,
        counted), or None: it is, and its binding moves on (a first ack binds its name)."""
        why = self._why(ack, header, now_ns)
        if why is None:
            bound = self._bound.pop(ack.node, None)
            if bound is None or bound.inc != header.inc:
                bound = _Binding(header.inc, header.seq, ack.sim_ns)
                self._pending.pop(ack.node, None)
            bound.seq, bound.sim_ns, bound.active = header.seq, ack.sim_ns, True
            self._bound[ack.node] = bound  # the most recently believed last
            while len(self._bound) > _MAX_NAMES and not next(iter(self._bound.values())).active:
                del self._bound[next(iter(self._bound))]
            return None
        self.refused[why] = self.refused.get(why, 0) + 1
        if why in ("other_incarnation", "not_present") and not ack.leaving:
            self._pending.pop(ack.node, None)
            self._pending[ack.node] = (ack, header)
            while len(self._pending) > MAX_PENDING:
                del self._pending[next(iter(self._pending))]
        return why

    def _why(self, ack: ClockAck, header: Header, now_ns: int) -> str | None:
        if header.node != ack.node:
            return "not_sender"
        if self._verify is not None and ack.node in self._expected and not self._verify(ack, header):
            return "bad_signature"
        bound = self._bound.get(ack.node)
        if bound is not None and header.inc == bound.inc:
            if header.seq <= bound.seq or ack.sim_ns < bound.sim_ns:
                return "out_of_order"
            if header.seq - bound.seq > MAX_SEQ_STEP:
                return "seq_jump"
        elif bound is not None and bound.active:
            return "other_incarnation"
        elif self._expected and ack.node not in self._expected and self._present.get(ack.node) != header.inc:
            return "not_present"
        if ack.sim_ns > now_ns and not ack.leaving:  # a leaving ack's time says nothing
            return "not_issued"
        return None

    def owns(self, node: str, inc: int) -> bool:
        """Whether ``node``'s binding is to incarnation ``inc`` (a heartbeat of that incarnation keeps it alive)."""
        bound = self._bound.get(node)
        return bound is not None and bound.active and bound.inc == inc

    def heard(self, node: str, inc: int) -> tuple[ClockAck, Header] | None:
        """A heartbeat of ``node``, incarnation ``inc``: its presence (outside ``expected``); the ack it kept
        waiting, to be checked again now, if any."""
        if not self._expected or node in self._expected:
            return None
        self._present.pop(node, None)
        self._present[node] = inc
        while len(self._present) > _MAX_PRESENT:
            del self._present[next(iter(self._present))]
        waiting = self._pending.get(node)
        bound = self._bound.get(node)
        if waiting is not None and not (bound is not None and bound.active) and waiting[1].inc == inc:
            return self._pending.pop(node)
        return None

    def release(self, node: str) -> tuple[ClockAck, Header] | None:
        """``node``'s incarnation no longer takes part (it left, or the clock dropped it): its name is free; the ack
        another incarnation sent under it meanwhile, to be checked again now, if any."""
        bound = self._bound.get(node)
        if bound is not None:
            bound.active = False
        return self._pending.pop(node, None)
