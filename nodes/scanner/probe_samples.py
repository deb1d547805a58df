"""Which probe measured a stiffness estimate: the adaptive planner's sorting of ``stiffness/sample`` by the probe
that measured it, told by where and when it was measured, not when it arrived.

Only what its probes measured where they were sent counts: the touch-off presses and the transit from the last of
them still in contact read 3-20x the tissue's stiffness (a false inclusion at each touch point). The scanner answers
a probe a while after its path ends, so estimates of the last probe keep arriving after the next one was asked for;
counted as the next probe's, a resolving sweep's stiff end went into the stiffness-blind baseline whenever a
covering sweep followed, raised the detector's threshold and lost a weak inclusion (fresh seed 5019, draw 2). And of
a probe's estimates only those of its measuring part count (the scanner's answer says when): the transit to a sweep,
often along the same column, passes over its line at the retract height, where the floating indenter still reads,
at another load (tuning phantom airfloat_tumours: the map's noise 0.075, the raster's 0.046).
"""

from __future__ import annotations

from typing import Literal

from messages import StiffnessSample

__all__ = ["Point", "ProbeSamples", "Sample"]

Point = tuple[float, float]
Sample = tuple[float, float, float, bool]
"""A kept estimate: x, y (mm), value, and whether a stiffness-blind probe measured it (it goes to the baseline)."""


class ProbeSamples:
    """The probe in flight and the last one answered, and the estimates kept of them until :meth:`take`.

    A sweep's line (``length_mm`` along y) or a press's ``radius_mm`` is where a probe measures, within
    ``tolerance_mm`` (one belief cell)."""

    def __init__(self, *, mode: Literal["sweep", "indent"], length_mm: float, radius_mm: float,
                 tolerance_mm: float) -> None:
        self._half = 0.5 * length_mm if mode == "sweep" else 0.0
        self._reach = tolerance_mm if mode == "sweep" else max(tolerance_mm, radius_mm)
        self.inflight: Point | None = None
        """The probe asked for and not answered yet."""
        self.inflight_blind = False
        """Whether the probe in flight was chosen without looking at stiffness."""
        self._since_ns = 0
        self._last: tuple[Point, bool, tuple[int, int]] | None = None
        """The last probe answered: its point, whether it was blind, its measuring span (ns; (0, 0): not said)."""
        self._held: list[tuple[float, float, float, int]] = []
        """The probe in flight's estimates (x, y, value, measured at), until its answer says when it measured."""
        self._pending: list[Sample] = []

    def sent(self, point: Point, blind: bool, now_ns: int) -> None:
        """A probe at ``point`` was asked for at ``now_ns``: it is in flight."""
        self.inflight, self.inflight_blind, self._since_ns = point, blind, now_ns

    def add(self, s: StiffnessSample) -> bool:
        """Keep ``s`` if a probe measured it on its measuring part; whether it lies on a probe at all (the probe in
        flight, measured since it was asked for, or the last one answered)."""
        blind = self.measured_by(s)
        if blind is None:
            return False
        if self._in_flight(s):
            self._held.append((s.x_mm, s.y_mm, s.value, s.stamp_ns))  # until its answer says when it measured
        elif self._last is not None and _within(self._last[2], s.stamp_ns):
            self._pending.append((s.x_mm, s.y_mm, s.value, blind))
        return True

    def measured_by(self, s: StiffnessSample) -> bool | None:
        """Whether the probe that measured ``s`` was stiffness-blind; None when ``s`` lies on neither the probe in
        flight nor the last one answered."""
        if self._in_flight(s):
            return self.inflight_blind
        if self._last is not None and self._on(self._last[0], s):
            return self._last[1]
        return None

    def answered(self, window: tuple[int, int]) -> tuple[Point, bool]:
        """The probe in flight was answered, having measured from ``window[0]`` to ``window[1]`` (ns; (0, 0): not
        said): its estimates of then are kept, and it becomes the last probe. Returns its point and blindness."""
        point, blind = self._land()
        self._pending += [(x, y, v, blind) for x, y, v, t in self._held if _within(window, t)]
        self._held.clear()
        self._last = (point, blind, window)
        return point, blind

    def refused(self) -> tuple[Point, bool]:
        """The probe in flight failed: it said nothing of when it measured, so none of its estimates is kept.
        Returns its point and blindness."""
        self._held.clear()
        return self._land()

    def take(self) -> list[Sample]:
        """The estimates kept since the last call."""
        out, self._pending = self._pending, []
        return out

    def _land(self) -> tuple[Point, bool]:
        if self.inflight is None:
            raise RuntimeError("no probe in flight")
        point, self.inflight = self.inflight, None
        return point, self.inflight_blind

    def _in_flight(self, s: StiffnessSample) -> bool:
        return self.inflight is not None and s.stamp_ns >= self._since_ns and self._on(self.inflight, s)

    def _on(self, probe: Point, s: StiffnessSample) -> bool:
        dy = max(0.0, abs(s.y_mm - probe[1]) - self._half)
        return (s.x_mm - probe[0]) ** 2 + dy**2 <= self._reach**2


def _within(window: tuple[int, int], stamp_ns: int) -> bool:
    """Whether an estimate measured at ``stamp_ns`` lies in a probe's measuring span (``(0, 0)``: not said, so
    yes)."""
    lo, hi = window
    return (lo == 0 and hi == 0) or lo <= stamp_ns <= hi
