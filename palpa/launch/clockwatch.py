"""The launcher's watch on a simulated clock, from outside the graph: has simulated time stopped moving?

A sim-clock graph that freezes (a node holding the lockstep clock for good, a clock that jumped out of reach)
looks alive from inside: the clock source still broadcasts the same instant every wall second and every node's
dead-clock guard is fed. Only the wall clock can tell, so this is one of the few places that reads it for a
decision: :class:`ClockWatch` takes the ticks the launcher hears on ``_palpa/clock`` and says when simulated time,
once started, has stood still for longer than the clock entry's ``frozen_after_s`` (wall seconds). The supervisor
then ends the launch non-zero with that reason; before that, once time has stood still for :data:`STALLED_S`, it
warns, and a Ctrl-C then says so and ends non-zero too.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from palpa.launch.compose import CLOCK_TARGET
from palpa.launch.plan import LaunchPlan
from palpa.runtime_msgs import ClockTick

__all__ = ["STALLED_S", "ClockWatch"]

STALLED_S = 10.0
"""Wall seconds of simulated time standing still (at most; half ``frozen_after_s`` if that is less) after which
the launcher warns and a Ctrl-C reports the graph as stalled."""


class ClockWatch:
    """Watches one simulated clock's ticks (wall-clock seconds: ``frozen_after_s``; ``wall`` is replaceable in
    tests)."""

    def __init__(self, frozen_after_s: float, wall: Callable[[], float] | None = None) -> None:
        self.frozen_after_s = frozen_after_s
        self._wall = wall or time.monotonic
        self.sim_ns: int | None = None
        """The latest instant heard (None: no tick yet, or time still held at its start)."""
        self._moved_at = 0.0
        self.warned = False
        """Whether this stall was warned of (once per stall)."""

    @classmethod
    def for_plan(cls, plan: LaunchPlan) -> ClockWatch | None:
        """A watch on the file's simulated clock (its ``palpa.timing.simclock:ClockSource`` entry), if it has one; its
        bound is that entry's ``frozen_after_s``."""
        for spec in plan.nodes:
            if spec.target == CLOCK_TARGET:
                # the node runtime, imported only for a file that has a clock source
                from palpa.timing.simclock import ClockSource

                return cls(float(spec.params.get("frozen_after_s", ClockSource.Params().frozen_after_s)))
        return None

    def on_tick(self, tick: ClockTick) -> None:
        """A tick heard on ``_palpa/clock``: a held start does not count (time has not started)."""
        if tick.hold:
            return
        if self.sim_ns is None or tick.sim_ns != self.sim_ns:
            self.sim_ns = tick.sim_ns
            self._moved_at = self._wall()
            self.warned = False

    def still_s(self) -> float:
        """Wall seconds simulated time has stood still (0 before it started)."""
        return 0.0 if self.sim_ns is None else self._wall() - self._moved_at

    def frozen(self) -> str:
        """Why the graph counts as frozen ('' while time moves, or has stood still for less than the bound)."""
        still = self.still_s()
        return self.stalled_text(still) if still > self.frozen_after_s else ""

    def stalled(self) -> str:
        """'' unless time has stood still for :data:`STALLED_S` (or half the bound), what a Ctrl-C then reports."""
        still = self.still_s()
        return self.stalled_text(still) if still > min(STALLED_S, self.frozen_after_s / 2) else ""

    def verdict(self) -> tuple[str, str]:
        """What the launcher does now: ``("frozen", why)`` end the launch (exit code 1); ``("stalled", why)`` warn
        (once per stall); ``("", "")`` nothing."""
        if why := self.frozen():
            return "frozen", why
        if not self.warned and (why := self.stalled()):
            self.warned = True
            return "stalled", f"{why}; the launch ends with exit code 1 after {self.frozen_after_s:g} s, or on Ctrl-C"
        return "", ""

    def stalled_text(self, still_s: float) -> str:
        """The reason in words, for ``still_s`` wall seconds standing still."""
        at = (self.sim_ns or 0) / 1e9
        return (f"simulated time has not moved for {still_s:.0f} s (wall clock), stuck at {at:.3f} s: the graph is "
                f"frozen (see the clock's log: a node holding it, or a jump it cannot reach)")
