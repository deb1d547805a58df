"""Boustrophedon raster paths over a rectangle of the phantom (issue 8), and a workspace check.

Frame: the phantom frame (mm), origin at a phantom corner, z up, table at z = 0. Lines run
parallel to ``axis`` ("y" by default, like the paper's Fig. 12 scan) and are stepped along the
other axis; every other line is reversed (boustrophedon). Lines (and indentation points along
a line) are spread evenly from edge to edge, so the actual spacing is the requested one or a
little less and both edges of the rectangle are always covered.

A :class:`Waypoint` is the target of one linear move (UR ``moveL``): ``speed_mm_s`` and
``accel_mm_s2`` apply to the move that ends there, ``hold_s`` is a dwell after arriving and
``blend_mm`` the blend radius through it (0 = stop exactly). Blends are only used where the
probe is off the tissue (transit, approach, lift, retract) and are clipped to half the shorter
adjacent segment (UR rejects overlapping blends); the first and last waypoints never blend.

Two modes:

* :func:`sweep_raster` -- per line: transit at retract height to above the line start,
  approach (down to approach height), contact (slow descent to the scan height
  ``contact_z_mm + offset_mm``), contact (slide to the line end at the scan speed), retract.
  Without a ``surface`` the scan height is constant, as in the paper.
* :func:`indent_raster` -- per grid point: approach (above the point), press (to
  ``contact_z_mm - depth_mm``), hold, lift (back to approach height); one transit at the
  start and one retract at the end.

Both take an optional ``surface``: a height profile z_s(x, y) (mm; e.g. ``models.surface.SurfaceFit``, what
the scanner's touch-off found). Every height is then taken over it -- ``contact_z_mm`` becomes the probe's working
offset above the surface -- a sweep line follows it with intermediate contact points (``follow_step_mm`` apart,
blended, only where the surface bends away from the straight line by more than 0.05 mm), and transit and retract
run at one height: the surface's top over the region plus the retract clearance.

The duration estimate assumes every move starts and ends at rest with a trapezoidal
velocity profile (blends ignored), so it is an upper bound for a blended path.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

__all__ = [
    "RasterPlan",
    "Waypoint",
    "WaypointKind",
    "WorkspaceBox",
    "WorkspaceViolation",
    "check_workspace",
    "estimate_duration_s",
    "indent_raster",
    "line_positions",
    "move_time_s",
    "sweep_raster",
]

WaypointKind = Literal["approach", "contact", "press", "hold", "lift", "retract", "transit"]
_BLENDED = frozenset({"approach", "lift", "retract", "transit"})
Surface = Callable[[float, float], float]
_FOLLOW_TOL_MM = 0.05


@dataclass(frozen=True, slots=True)
class Waypoint:
    """Target of one linear move; see the module docstring for the meaning of each field."""

    x_mm: float
    y_mm: float
    z_mm: float
    speed_mm_s: float
    accel_mm_s2: float
    blend_mm: float
    hold_s: float
    line: int  # 0-based raster line this waypoint belongs to
    kind: WaypointKind


@dataclass(frozen=True, slots=True)
class RasterPlan:
    """A planned raster: waypoints in order, number of lines, estimated duration (s)."""

    waypoints: tuple[Waypoint, ...]
    line_count: int
    duration_s: float
    line_spacing_mm: float  # actual spacing between lines (<= the requested one)
    mode: Literal["sweep", "indent"]


@dataclass(frozen=True, slots=True)
class WorkspaceBox:
    """Axis-aligned box (mm, phantom frame) the probe tip must stay inside."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    z_min: float
    z_max: float

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, f"{axis}_min"), getattr(self, f"{axis}_max")
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(
                    f"WorkspaceBox: need finite {axis}_min <= {axis}_max, got {lo} and {hi}"
                )


class WorkspaceViolation(ValueError):
    """A waypoint lies outside the workspace box (or has a non-finite coordinate)."""

    def __init__(self, index: int, waypoint: Waypoint, bound: str, limit: float) -> None:
        self.index = index
        self.waypoint = waypoint
        self.bound = bound  # "x_min", ..., "z_max", or "finite"
        self.limit = limit
        where = f"x={waypoint.x_mm:g}, y={waypoint.y_mm:g}, z={waypoint.z_mm:g} mm"
        if bound == "finite":
            what = "has a non-finite coordinate"
        else:
            side = "below" if bound.endswith("_min") else "above"
            what = f"is {side} the workspace's {bound}={limit:g} mm"
        super().__init__(
            f"waypoint {index} ({waypoint.kind}, line {waypoint.line}, {where}) {what}"
        )


def check_workspace(waypoints: Sequence[Waypoint], box: WorkspaceBox) -> None:
    """Raise :class:`WorkspaceViolation` for the first waypoint outside ``box`` (edges allowed)."""
    for i, wp in enumerate(waypoints):
        for axis, value in (("x", wp.x_mm), ("y", wp.y_mm), ("z", wp.z_mm)):
            if not math.isfinite(value):
                raise WorkspaceViolation(i, wp, "finite", math.nan)
            lo, hi = getattr(box, f"{axis}_min"), getattr(box, f"{axis}_max")
            if value < lo:
                raise WorkspaceViolation(i, wp, f"{axis}_min", lo)
            if value > hi:
                raise WorkspaceViolation(i, wp, f"{axis}_max", hi)


def move_time_s(distance_mm: float, speed_mm_s: float, accel_mm_s2: float) -> float:
    """Time (s) of a rest-to-rest move with a trapezoidal (or triangular) speed profile."""
    if distance_mm <= 0:
        return 0.0
    if distance_mm >= speed_mm_s * speed_mm_s / accel_mm_s2:
        return distance_mm / speed_mm_s + speed_mm_s / accel_mm_s2
    return 2.0 * math.sqrt(distance_mm / accel_mm_s2)


def estimate_duration_s(waypoints: Sequence[Waypoint]) -> float:
    """Estimated time (s) from the first waypoint to the end of the last one's dwell."""
    total = waypoints[0].hold_s if waypoints else 0.0
    for a, b in zip(waypoints, waypoints[1:], strict=False):
        dist = math.dist((a.x_mm, a.y_mm, a.z_mm), (b.x_mm, b.y_mm, b.z_mm))
        total += move_time_s(dist, b.speed_mm_s, b.accel_mm_s2) + b.hold_s
    return total


def line_positions(lo_mm: float, hi_mm: float, spacing_mm: float) -> list[float]:
    """Evenly spread positions from ``lo_mm`` to ``hi_mm`` (both included) no more than
    ``spacing_mm`` apart; a single position when lo == hi."""
    _positive("spacing_mm", spacing_mm)
    if not (math.isfinite(lo_mm) and math.isfinite(hi_mm) and lo_mm <= hi_mm):
        raise ValueError(f"raster: need finite lo <= hi, got {lo_mm} and {hi_mm}")
    gaps = max(1, math.ceil((hi_mm - lo_mm) / spacing_mm - 1e-9)) if hi_mm > lo_mm else 0
    if gaps == 0:
        return [lo_mm]
    return [lo_mm + (hi_mm - lo_mm) * i / gaps for i in range(gaps + 1)]


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"raster: {name} must be a finite number > 0, got {value}")


def _lines(
    x0: float, y0: float, x1: float, y1: float, spacing: float, along_step: float | None, axis: str
) -> tuple[list[list[tuple[float, float]]], float]:
    """Points of each line in travel order (boustrophedon) and the actual line spacing."""
    if axis not in ("x", "y"):
        raise ValueError(f"raster: axis must be 'x' or 'y', got {axis!r}")
    (c0, c1), (a0, a1) = ((x0, x1), (y0, y1)) if axis == "y" else ((y0, y1), (x0, x1))
    across = line_positions(c0, c1, spacing)
    along = [a0, a1] if along_step is None else line_positions(a0, a1, along_step)
    lines = []
    for i, c in enumerate(across):
        seq = along if i % 2 == 0 else along[::-1]
        lines.append([(c, a) if axis == "y" else (a, c) for a in seq])
    actual = across[1] - across[0] if len(across) > 1 else 0.0
    return lines, actual


def _blend(points: list[Waypoint], blend_mm: float) -> tuple[Waypoint, ...]:
    out = []
    for i, wp in enumerate(points):
        r = 0.0
        if wp.kind in _BLENDED and 0 < i < len(points) - 1 and blend_mm > 0:
            here = (wp.x_mm, wp.y_mm, wp.z_mm)
            prev = points[i - 1]
            nxt = points[i + 1]
            d_in = math.dist((prev.x_mm, prev.y_mm, prev.z_mm), here)
            d_out = math.dist(here, (nxt.x_mm, nxt.y_mm, nxt.z_mm))
            r = min(blend_mm, 0.5 * d_in, 0.5 * d_out)
        out.append(Waypoint(wp.x_mm, wp.y_mm, wp.z_mm, wp.speed_mm_s, wp.accel_mm_s2, r,
                            wp.hold_s, wp.line, wp.kind))  # fmt: skip
    return tuple(out)


def sweep_raster(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    *,
    spacing_mm: float,
    speed_mm_s: float,
    contact_z_mm: float,
    offset_mm: float = 0.0,
    approach_clearance_mm: float = 5.0,
    retract_clearance_mm: float = 20.0,
    axis: Literal["x", "y"] = "y",
    approach_speed_mm_s: float = 5.0,
    transit_speed_mm_s: float = 50.0,
    accel_mm_s2: float = 500.0,
    blend_mm: float = 0.0,
    surface: Surface | None = None,
    follow_step_mm: float = 2.0,
) -> RasterPlan:
    """Sliding raster: the probe stays at ``contact_z_mm + offset_mm`` along each line (over ``surface`` when
    given: see the module docstring).

    ``offset_mm`` > 0 leaves a clearance (the air-float probe's air gap), < 0 presses in.
    Approach and retract heights are ``contact_z_mm`` plus the clearances (mm); speeds mm/s,
    acceleration mm/s^2 (one value for every move), blend radius mm.
    """
    _check_common(
        blend_mm,
        speed_mm_s=speed_mm_s,
        approach_speed_mm_s=approach_speed_mm_s,
        transit_speed_mm_s=transit_speed_mm_s,
        accel_mm_s2=accel_mm_s2,
        approach_clearance_mm=approach_clearance_mm,
        retract_clearance_mm=retract_clearance_mm,
    )
    scan_z = contact_z_mm + offset_mm
    approach_z = contact_z_mm + approach_clearance_mm
    retract_z = contact_z_mm + retract_clearance_mm
    if not (math.isfinite(scan_z) and scan_z <= approach_z <= retract_z):
        raise ValueError(
            "sweep_raster: need scan height <= approach height <= retract height, got "
            f"{scan_z} <= {approach_z} <= {retract_z} mm"
        )
    lines, actual = _lines(x0, y0, x1, y1, spacing_mm, None, axis)
    acc, fast, slow = accel_mm_s2, transit_speed_mm_s, approach_speed_mm_s
    zs = _heights(surface, lines, follow_step_mm)
    if surface is not None:
        retract_z += zs.top
    pts: list[Waypoint] = []
    for i, ((xs, ys), (xe, ye)) in enumerate(lines):
        follow = zs.along(xs, ys, xe, ye)
        pts += [
            Waypoint(xs, ys, retract_z, fast, acc, 0.0, 0.0, i, "transit"),
            Waypoint(xs, ys, approach_z + follow[0][2], fast, acc, 0.0, 0.0, i, "approach"),
            Waypoint(xs, ys, scan_z + follow[0][2], slow, acc, 0.0, 0.0, i, "contact"),
        ]
        pts += [Waypoint(x, y, scan_z + z, speed_mm_s, acc, 0.0, 0.0, i, "contact") for x, y, z in follow[1:]]
        pts.append(Waypoint(xe, ye, retract_z, fast, acc, 0.0, 0.0, i, "retract"))
    wps = _blend_following(_blend(pts, blend_mm), 0.45 * follow_step_mm)
    return RasterPlan(wps, len(lines), estimate_duration_s(wps), actual, "sweep")


def indent_raster(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    *,
    spacing_mm: float,
    contact_z_mm: float,
    depth_mm: float,
    hold_s: float,
    point_spacing_mm: float | None = None,
    approach_clearance_mm: float = 5.0,
    retract_clearance_mm: float = 20.0,
    axis: Literal["x", "y"] = "y",
    press_speed_mm_s: float = 2.0,
    transit_speed_mm_s: float = 50.0,
    accel_mm_s2: float = 500.0,
    blend_mm: float = 0.0,
    surface: Surface | None = None,
) -> RasterPlan:
    """Indentation grid: at each point approach, press ``depth_mm`` below ``contact_z_mm`` (over ``surface``
    when given: see the module docstring),
    hold ``hold_s`` seconds, lift; points ``point_spacing_mm`` apart along each line
    (default: ``spacing_mm``). Press and lift run at ``press_speed_mm_s``, the rest at the
    transit speed; units as in :func:`sweep_raster`.
    """
    _check_common(
        blend_mm,
        press_speed_mm_s=press_speed_mm_s,
        transit_speed_mm_s=transit_speed_mm_s,
        accel_mm_s2=accel_mm_s2,
        depth_mm=depth_mm,
        approach_clearance_mm=approach_clearance_mm,
        retract_clearance_mm=retract_clearance_mm,
    )
    if not (math.isfinite(hold_s) and hold_s >= 0):
        raise ValueError(f"indent_raster: hold_s must be finite and >= 0, got {hold_s}")
    press_z = contact_z_mm - depth_mm
    approach_z = contact_z_mm + approach_clearance_mm
    retract_z = contact_z_mm + retract_clearance_mm
    if not (math.isfinite(press_z) and contact_z_mm <= approach_z <= retract_z):
        raise ValueError(
            "indent_raster: need contact height <= approach height <= retract height, got "
            f"{contact_z_mm} <= {approach_z} <= {retract_z} mm"
        )
    step = spacing_mm if point_spacing_mm is None else point_spacing_mm
    lines, actual = _lines(x0, y0, x1, y1, spacing_mm, step, axis)
    acc, fast, slow = accel_mm_s2, transit_speed_mm_s, press_speed_mm_s
    zs = _heights(surface, lines, None)
    if surface is not None:
        retract_z += zs.top
    first = lines[0][0]
    pts = [Waypoint(first[0], first[1], retract_z, fast, acc, 0.0, 0.0, 0, "transit")]
    for i, line in enumerate(lines):
        for x, y in line:
            z = zs.at(x, y)
            pts += [
                Waypoint(x, y, approach_z + z, fast, acc, 0.0, 0.0, i, "approach"),
                Waypoint(x, y, press_z + z, slow, acc, 0.0, 0.0, i, "press"),
                Waypoint(x, y, press_z + z, slow, acc, 0.0, hold_s, i, "hold"),
                Waypoint(x, y, approach_z + z, slow, acc, 0.0, 0.0, i, "lift"),
            ]
    last = pts[-1]
    pts.append(Waypoint(last.x_mm, last.y_mm, retract_z, fast, acc, 0.0, 0.0, last.line, "retract"))
    wps = _blend(pts, blend_mm)
    return RasterPlan(wps, len(lines), estimate_duration_s(wps), actual, "indent")


class _Heights:
    """The surface's heights where a plan needs them (all 0 without a surface)."""

    def __init__(self, surface: Surface | None, step_mm: float) -> None:
        self.surface, self.step = surface, step_mm
        self.top = -math.inf

    def at(self, x: float, y: float) -> float:
        if self.surface is None:
            return 0.0
        z = float(self.surface(x, y))
        if not math.isfinite(z):
            raise ValueError(f"raster: the surface is not finite at ({x:g}, {y:g}) mm")
        self.top = max(self.top, z)
        return z

    def along(self, xs: float, ys: float, xe: float, ye: float) -> list[tuple[float, float, float]]:
        """(x, y, z) from the line's start to its end: the ends, plus every step where the surface bends away
        from the straight line between them."""
        ends = [(xs, ys, self.at(xs, ys)), (xe, ye, self.at(xe, ye))]
        if self.surface is None:
            return ends
        n = max(1, math.ceil(math.dist((xs, ys), (xe, ye)) / self.step - 1e-9))
        pts = [(xs + (xe - xs) * k / n, ys + (ye - ys) * k / n) for k in range(n + 1)]
        prof = [(x, y, self.at(x, y)) for x, y in pts]
        chord = [ends[0][2] + (ends[1][2] - ends[0][2]) * k / n for k in range(n + 1)]
        if max(abs(p[2] - c) for p, c in zip(prof, chord, strict=True)) <= _FOLLOW_TOL_MM:
            return ends
        return prof


def _heights(surface: Surface | None, lines: list[list[tuple[float, float]]], step_mm: float | None) -> _Heights:
    """Heights over every line (so that ``top`` covers the region before any waypoint is made)."""
    if step_mm is not None:
        _positive("follow_step_mm", step_mm)
    hs = _Heights(surface, step_mm or 1.0)
    for line in lines:
        if step_mm is None:
            for x, y in line:
                hs.at(x, y)
        else:
            hs.along(*line[0], *line[-1])
    return hs


def _blend_following(points: tuple[Waypoint, ...], blend_mm: float) -> tuple[Waypoint, ...]:
    """Blend the intermediate points of a followed contact line (not its ends), so that the probe glides."""
    out = list(points)
    for i in range(1, len(out) - 1):
        prev, wp, nxt = out[i - 1], out[i], out[i + 1]
        if wp.kind == prev.kind == nxt.kind == "contact" and prev.speed_mm_s == wp.speed_mm_s:
            here = (wp.x_mm, wp.y_mm, wp.z_mm)
            r = min(blend_mm, 0.5 * math.dist((prev.x_mm, prev.y_mm, prev.z_mm), here),
                    0.5 * math.dist(here, (nxt.x_mm, nxt.y_mm, nxt.z_mm)))
            out[i] = Waypoint(wp.x_mm, wp.y_mm, wp.z_mm, wp.speed_mm_s, wp.accel_mm_s2, r, wp.hold_s, wp.line,
                              wp.kind)
    return tuple(out)


def _check_common(blend_mm: float, **positive: float) -> None:
    for name, value in positive.items():
        _positive(name, value)
    if not (math.isfinite(blend_mm) and blend_mm >= 0):
        raise ValueError(f"raster: blend_mm must be finite and >= 0, got {blend_mm}")
