"""Clocks: where a node gets its time.

Stamps on the wire are wall-clock nanoseconds since the Unix epoch (``time.time_ns``) so that processes and
recordings agree. Timers run on the same clock's notion of time; :class:`MockClock` lets tests move time by hand,
so node logic with timers is tested without waiting.
"""

from __future__ import annotations

import time
from typing import Protocol

__all__ = ["Clock", "MockClock", "SystemClock", "TopicClock"]


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
