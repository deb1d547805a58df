"""Surface following during a sweep: keep the air-float probe's face at its working clearance from the tissue
by its own heights, whatever the fitted surface got wrong.

The touch-off fits a smooth surface through a few points; a raster planned over it is only as right as the fit
(a coarse grid on a dome can be a millimetre off between its points). While the probe slides along a line its
three surface-profile sensors measure the face's normal distance to the tissue, eq. 2's d_n
(``models.airfloat.surface_distance``). The law here moves the line's heights by an offset ``u``
(mm, added to every remaining height of the line as planned) so that d_n stays at the working clearance:

    e = min(d_n - target, min(h1, h2, h3) - min_sps)
    u <- clamp(u - clamp(gain * dt * e, +-max_rate * dt), lo, hi)

an integral law (the plan's own slope is the feed-forward; the measurement corrects the offset), its rate capped so
that one bad sample cannot jerk the arm, ``u`` bounded by ``max_offset_mm`` and by the workspace box (``lo``, ``hi``:
the caller's limits). The second term of ``e``: on a slope the uphill SPS comes closer to the face than d_n says
(by about ``slope * a``), and an SPS pushed back to the face reads 0 and no longer sees the plane, so the face is
also kept ``min_sps`` clear of the highest point under the ring. A sample is not used when its SPS disagree by more than ``max_spread_mm``
(one hangs over an edge) or one of them reads the end of its stroke (it sees nothing).

The indentation's working range (:func:`in_working_range`): the SPS ring floats clear of the face (each SPS above
``min_sps_mm``; at 0 the face itself rests on the tissue and eqs. 1-3 see the face, not the tissue's plane) and the
indenter's extension h4 stays ``stroke_margin_mm`` inside its stroke (beyond it the indenter no longer reaches the
depth the force would give). Pure functions; the scanner (nodes/scanner/robot_scanner.py) feeds them the probe's samples.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from models.airfloat import DEFAULT_SPS_RADIUS_MM, surface_distance
from models.raster import Waypoint

__all__ = ["FollowConfig", "clearance_error", "densify_slides", "follow_step", "gap_from_heights", "in_working_range",
           "is_slide", "shift_line"]


@dataclass(frozen=True)
class FollowConfig:
    """Gains and limits of the following law (mm, s)."""

    target_gap_mm: float = 1.0
    """d_n to hold: the face's clearance above the tissue (the paper's 1 mm)."""
    gain_per_s: float = 10.0
    """Fraction of the clearance error taken out per second (1/s): a time constant of 1/gain."""
    max_rate_mm_s: float = 5.0
    """The offset never changes faster than this (mm/s)."""
    max_offset_mm: float = 3.0
    """The line never moves more than this from its plan (mm)."""
    min_sps_mm: float = 0.3
    """Every SPS at least this far out of the face (none pushed back to it: see the module)."""
    max_spread_mm: float = 3.0
    stroke_mm: float = 10.0
    sps_radius_mm: float = DEFAULT_SPS_RADIUS_MM

    def __post_init__(self) -> None:
        for name in ("target_gap_mm", "gain_per_s", "min_sps_mm", "max_rate_mm_s", "max_offset_mm", "max_spread_mm", "stroke_mm",
                     "sps_radius_mm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FollowConfig: {name} must be finite and > 0, got {v!r}")


def gap_from_heights(h_mm: Sequence[float], cfg: FollowConfig) -> float | None:
    """Eq. 2's d_n (mm) from SPS1..3 (``h_mm[:3]``), or None when the sample cannot tell the surface (spread too
    wide, an SPS at the end of its stroke, not finite)."""
    h = [float(v) for v in h_mm[:3]]
    if len(h) < 3 or not all(math.isfinite(v) for v in h):
        return None
    if max(h) - min(h) > cfg.max_spread_mm or max(h) >= cfg.stroke_mm - 1e-6:
        return None
    return surface_distance(h[0], h[1], h[2], cfg.sps_radius_mm)


def clearance_error(h_mm: Sequence[float], cfg: FollowConfig) -> float | None:
    """The law's error e (mm; > 0: the face is too high), or None when the sample cannot tell the surface."""
    gap = gap_from_heights(h_mm, cfg)
    if gap is None:
        return None
    return min(gap - cfg.target_gap_mm, min(float(v) for v in h_mm[:3]) - cfg.min_sps_mm)


def follow_step(offset_mm: float, error_mm: float, dt_s: float, cfg: FollowConfig,
                limits_mm: tuple[float, float] = (-math.inf, math.inf)) -> float:
    """The offset after one sample: ``error_mm`` (:func:`clearance_error`), ``dt_s`` since the previous sample
    (see the module). ``limits_mm`` (lo, hi) narrow the ``max_offset_mm`` bounds (the workspace box)."""
    if not (math.isfinite(error_mm) and math.isfinite(dt_s)) or dt_s <= 0:
        return offset_mm
    step = cfg.gain_per_s * dt_s * error_mm
    cap = cfg.max_rate_mm_s * dt_s
    u = offset_mm - max(-cap, min(cap, step))
    lo = max(-cfg.max_offset_mm, limits_mm[0])
    hi = min(cfg.max_offset_mm, limits_mm[1])
    return max(lo, min(hi, u)) if lo <= hi else offset_mm


def in_working_range(h_mm: Sequence[float], *, min_sps_mm: float = 0.05, stroke_mm: float = 10.0,
                     stroke_margin_mm: float = 0.5) -> bool:
    """True when the sample's SPS all float clear of the face and the indenter is inside its stroke (module)."""
    h = [float(v) for v in h_mm[:4]]
    return min(h[:3]) > min_sps_mm and max(h[:3]) < stroke_mm and h[3] < stroke_mm - stroke_margin_mm


def is_slide(waypoints: Sequence[Waypoint], i: int) -> bool:
    """True when the move ending at waypoint ``i`` slides along a sweep line (a contact move from a contact
    waypoint of the same line; the first contact waypoint of a line is the descent onto it)."""
    if not 0 < i < len(waypoints):
        return False
    w, prev = waypoints[i], waypoints[i - 1]
    return w.kind == prev.kind == "contact" and w.line == prev.line


def densify_slides(waypoints: Sequence[Waypoint], step_mm: float) -> tuple[Waypoint, ...]:
    """Insert waypoints at most ``step_mm`` apart along every slide (blended, radius 0.45 step), so that a height
    correction takes effect within one step of travel rather than at the end of a straight line."""
    if not (math.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"densify_slides: step_mm must be finite and > 0, got {step_mm!r}")
    out: list[Waypoint] = []
    for i, w in enumerate(waypoints):
        if is_slide(waypoints, i):
            p = waypoints[i - 1]
            n = math.ceil(math.dist((p.x_mm, p.y_mm, p.z_mm), (w.x_mm, w.y_mm, w.z_mm)) / step_mm)
            for k in range(1, n):
                f = k / n
                out.append(Waypoint(p.x_mm + f * (w.x_mm - p.x_mm), p.y_mm + f * (w.y_mm - p.y_mm),
                                    p.z_mm + f * (w.z_mm - p.z_mm), w.speed_mm_s, w.accel_mm_s2, 0.45 * step_mm, 0.0,
                                    w.line, "contact"))
        out.append(w)
    return tuple(out)


def shift_line(waypoints: Sequence[Waypoint], line: int, offset_mm: float) -> tuple[Waypoint, ...]:
    """``waypoints`` with every contact waypoint of ``line`` raised by ``offset_mm`` (the follower's offset)."""
    return tuple(Waypoint(w.x_mm, w.y_mm, w.z_mm + offset_mm, w.speed_mm_s, w.accel_mm_s2, w.blend_mm, w.hold_s,
                          w.line, w.kind) if w.kind == "contact" and w.line == line and offset_mm else w
                 for w in waypoints)
