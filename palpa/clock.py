"""Clocks: where a node gets its time.

Stamps on the wire are wall-clock nanoseconds since the Unix epoch (``time.time_ns``) so that processes and
recordings agree. Timers run on the same clock's notion of time; :class:`MockClock` lets tests move time by hand,
so node logic with timers is tested without waiting.
"""

from __future__ import annotations

import time
from typing import Protocol

__all__ = ["Clock", "MockClock", "SystemClock"]


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
