"""Clocks: where a node gets its time.

Stamps on the wire are wall-clock nanoseconds since the Unix epoch (``time.time_ns``) so that processes and
recordings agree. Timers run on the same clock's notion of time; :class:`MockClock` lets tests move time by hand,
so node logic with timers is tested without waiting. :class:`Deadline` is how every wait and time limit in the
product reads its node's clock (tests/test_architecture.py holds product code to it).
"""

from __future__ import annotations

import math
import time
from typing import Protocol

__all__ = ["FROZEN_ROUNDS", "Clock", "Deadline", "MockClock", "SystemClock", "TopicClock"]


class Clock(Protocol):
    """The time source of a node."""

    def now_ns(self) -> int:
        """Current time in ns since the Unix epoch (or since the mock clock's origin)."""
        ...

    def is_real(self) -> bool:
        """True when time advances by itself (the node loop may block waiting for it)."""
        ...


class SystemClock:
    """Wall-clock time (``time.time_ns``)."""

    def now_ns(self) -> int:
        return time.time_ns()

    def is_real(self) -> bool:
        return True


class MockClock:
    """A clock that moves only when told to: ``advance(seconds)`` or ``set(ns)``."""

    def __init__(self, start_ns: int = 1_700_000_000_000_000_000) -> None:
        self._now = start_ns

    def now_ns(self) -> int:
        return self._now

    def is_real(self) -> bool:
        return False

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds`` (>= 0)."""
        if seconds < 0:
            raise ValueError(f"a clock cannot go backwards (advance by {seconds} s)")
        self._now += int(round(seconds * 1e9))

    def set(self, now_ns: int) -> None:
        """Jump to ``now_ns``; it must not be earlier than the current time."""
        if now_ns < self._now:
            raise ValueError(f"a clock cannot go backwards ({now_ns} < {self._now})")
        self._now = now_ns


class TopicClock:
    """Simulation time driven by ``ClockTick`` messages on ``_palpa/clock`` (``palpa play --clock``).

    Before the first tick the time is 0 and no timer fires; afterwards it is the latest tick's ``sim_ns``. A node
    gets one with ``--sim-clock`` (or ``PALPA_SIM_CLOCK=1``), so it behaves on a bag as it did live.
    """

    def __init__(self) -> None:
        self._now = 0
        self.started = False

    def now_ns(self) -> int:
        return self._now

    def is_real(self) -> bool:
        return True

    def update(self, sim_ns: int) -> None:
        """Take a tick; time never goes backwards except on a big jump back (a looped recording restarts)."""
        if sim_ns >= self._now or self._now - sim_ns > 1_000_000_000:
            self._now = sim_ns
        self.started = True


FROZEN_ROUNDS = 1000
"""Checks of a :class:`Deadline` on a simulated clock after which the deadline counts as passed although that clock
stood still through all of them. A :class:`MockClock` moves only when its executor moves it, and a node blocked in a
wait is that executor's thread, so no time can pass until the wait ends; by then the rest of the graph (pumped by the
wait) has had this many rounds to answer, far more than the hops any in-memory exchange needs. A
:class:`TopicClock` that stops (a lockstep clock holding time for the very node that waits, a paused replay) would
otherwise hold a wait for good. Rounds, not seconds: a busy machine cannot end the wait sooner."""


def _monotonic_ns() -> int:
    return time.monotonic_ns()


class Deadline:
    """A time limit read on a node's clock: ``Deadline(node.clock, 2.0)`` ends 2 s of that clock from now (None: never).

    On a :class:`SystemClock` durations are measured on the monotonic clock behind it (a wall-clock step by NTP must
    neither fire nor stretch a limit), so a wall-clock node waits exactly as long as before. On a simulated clock the
    limit is simulated time: a machine too busy to keep up cannot make it fire early; one that stands still while
    the waiter waits ends it after :data:`FROZEN_ROUNDS` checks.
    """

    def __init__(self, clock: Clock, seconds: float | None) -> None:
        wall = isinstance(clock, SystemClock)
        self._read = _monotonic_ns if wall else clock.now_ns
        self._frozen = not clock.is_real()
        """Time cannot move while the waiter blocks (a mock clock): nothing to wait for between rounds."""
        self._counts_rounds = not wall
        self._checks = 0
        self._last = self._read()
        self.at_ns: int | None = None if seconds is None else self._last + int(round(seconds * 1e9))
        """When it passes, on :meth:`now_ns`'s scale (None: never)."""

    def now_ns(self) -> int:
        """The current reading of the clock the limit is measured on (not necessarily epoch ns)."""
        return self._read()

    def remaining_s(self) -> float:
        """Seconds left (0 once passed; ``math.inf`` without a limit); a clock that does not move by itself gives
        no time to wait for: 0."""
        if self.at_ns is None:
            return 0.0 if self._frozen else math.inf
        return 0.0 if self._frozen else max(0.0, (self.at_ns - self._read()) / 1e9)

    def reached(self) -> bool:
        """Whether the clock has reached the limit, without counting a round: for a limit checked by someone
        other than its waiter (the frozen-clock rule is the waiter's alone)."""
        return self.at_ns is not None and self._read() >= self.at_ns

    def passed(self) -> bool:
        """Whether the limit is reached; call it once per round of a wait (the frozen-clock rule counts them)."""
        now = self._read()
        if self.at_ns is not None and now >= self.at_ns:
            return True
        if not self._counts_rounds:
            return False
        self._checks = self._checks + 1 if now == self._last else 0
        self._last = now
        return self.at_ns is not None and self._checks >= FROZEN_ROUNDS
