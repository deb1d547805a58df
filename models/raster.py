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
  The scan height is constant: like the paper, the path does not follow the surface.
* :func:`indent_raster` -- per grid point: approach (above the point), press (to
  ``contact_z_mm - depth_mm``), hold, lift (back to approach height); one transit at the
  start and one retract at the end.

The duration estimate assumes every move starts and ends at rest with a trapezoidal
velocity profile (blends ignored), so it is an upper bound for a blended path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
) -> RasterPlan:
    """Sliding raster: the probe stays at ``contact_z_mm + offset_mm`` along each line.

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
    pts: list[Waypoint] = []
    for i, ((xs, ys), (xe, ye)) in enumerate(lines):
        pts += [
            Waypoint(xs, ys, retract_z, fast, acc, 0.0, 0.0, i, "transit"),
            Waypoint(xs, ys, approach_z, fast, acc, 0.0, 0.0, i, "approach"),
            Waypoint(xs, ys, scan_z, slow, acc, 0.0, 0.0, i, "contact"),
            Waypoint(xe, ye, scan_z, speed_mm_s, acc, 0.0, 0.0, i, "contact"),
            Waypoint(xe, ye, retract_z, fast, acc, 0.0, 0.0, i, "retract"),
        ]
    wps = _blend(pts, blend_mm)
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
) -> RasterPlan:
    """Indentation grid: at each point approach, press ``depth_mm`` below ``contact_z_mm``,
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
    first = lines[0][0]
    pts = [Waypoint(first[0], first[1], retract_z, fast, acc, 0.0, 0.0, 0, "transit")]
    for i, line in enumerate(lines):
        for x, y in line:
            pts += [
                Waypoint(x, y, approach_z, fast, acc, 0.0, 0.0, i, "approach"),
                Waypoint(x, y, press_z, slow, acc, 0.0, 0.0, i, "press"),
                Waypoint(x, y, press_z, slow, acc, 0.0, hold_s, i, "hold"),
                Waypoint(x, y, approach_z, slow, acc, 0.0, 0.0, i, "lift"),
            ]
    last = pts[-1]
    pts.append(Waypoint(last.x_mm, last.y_mm, retract_z, fast, acc, 0.0, 0.0, last.line, "retract"))
    wps = _blend(pts, blend_mm)
    return RasterPlan(wps, len(lines), estimate_duration_s(wps), actual, "indent")


def _check_common(blend_mm: float, **positive: float) -> None:
    for name, value in positive.items():
        _positive(name, value)
    if not (math.isfinite(blend_mm) and blend_mm >= 0):
        raise ValueError(f"raster: blend_mm must be finite and >= 0, got {blend_mm}")
