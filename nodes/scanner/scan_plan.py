"""The robot scanner's plan and the safety envelope every path passes before it moves the arm.

:func:`plan_raster` makes the raster the scanner's parameters ask for over its specimen (a sweep, densified where
its lines are followed, or an indentation); :func:`check_path` refuses a path (a scan's, a probe's, a following
correction's) that leaves the workspace box or exceeds the speed or acceleration cap, naming the waypoint, or any
path at all while the arm is outside the box; :func:`path_segments` cuts a path where the arm stops anyway. Split
from nodes/scanner/robot_scanner.py, which drives the arm along what these plan and pass.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import palpa
from models.following import densify_slides
from models.raster import (
    RasterPlan,
    Waypoint,
    WorkspaceBox,
    WorkspaceViolation,
    check_workspace,
    indent_raster,
    sweep_raster,
)
from nodes.drivers.robot import RobotDriver
from nodes.scanner.specimen import SpecimenPlanner

if TYPE_CHECKING:
    from nodes.scanner.robot_scanner import RobotScanner

__all__ = ["check_path", "path_segments", "plan_raster"]


def plan_raster(p: RobotScanner.Params, specimen: SpecimenPlanner, following: bool) -> RasterPlan:
    """The scan's raster over the specimen's region at its planned heights (``following``: a sweep's lines are
    followed, their slides cut into steps of ``follow_step_mm``)."""
    x0, y0, x1, y1 = specimen.region
    common: dict[str, Any] = dict(
        spacing_mm=p.spacing_mm, axis=p.axis, accel_mm_s2=p.accel_mm_s2,
        approach_clearance_mm=p.approach_clearance_mm, retract_clearance_mm=p.retract_clearance_mm,
        transit_speed_mm_s=p.transit_speed_mm_s, **specimen.plan_heights(),
    )
    if p.mode == "sweep":
        plan = sweep_raster(x0, y0, x1, y1, speed_mm_s=p.speed_mm_s,
                            approach_speed_mm_s=p.approach_speed_mm_s, **common)
        if not following:
            return plan
        return dataclasses.replace(plan, waypoints=densify_slides(plan.waypoints, p.follow_step_mm))
    # indent: press and lift at speed_mm_s
    return indent_raster(x0, y0, x1, y1, depth_mm=specimen.press_depth_mm(),
                         hold_s=p.hold_s, point_spacing_mm=p.point_spacing_mm or None,
                         press_speed_mm_s=p.speed_mm_s, **common)


def check_path(waypoints: tuple[Waypoint, ...], p: RobotScanner.Params, name: str, driver: RobotDriver) -> None:
    """Raise ParamError naming the first waypoint that leaves the workspace box or exceeds a cap (and when
    the arm itself is outside the box)."""
    x0, y0, z0, x1, y1, z1 = p.workspace_mm
    try:
        box = WorkspaceBox(x0, x1, y0, y1, z0, z1)
    except ValueError as exc:
        raise palpa.ParamError(f"{name}: workspace_mm: {exc}") from None
    x, y, z = driver.state().pose[:3]
    start = Waypoint(x, y, z, 0.0, 0.0, 0.0, 0.0, -1, "transit")
    try:
        check_workspace([start], box)
    except WorkspaceViolation as exc:
        raise palpa.ParamError(f"{name}: refusing to move: the arm's current pose is outside the "
                               f"workspace box ({exc})") from None
    try:
        check_workspace(waypoints, box)
    except WorkspaceViolation as exc:
        raise palpa.ParamError(f"{name}: refusing the plan before any motion: {exc}") from None
    for i, w in enumerate(waypoints):
        if w.speed_mm_s > p.max_speed_mm_s or w.accel_mm_s2 > p.max_accel_mm_s2:
            raise palpa.ParamError(
                f"{name}: refusing the plan before any motion: waypoint {i} ({w.kind}, line {w.line}) "
                f"asks {w.speed_mm_s:g} mm/s, {w.accel_mm_s2:g} mm/s² over the caps "
                f"{p.max_speed_mm_s:g} mm/s, {p.max_accel_mm_s2:g} mm/s²")


def path_segments(waypoints: tuple[Waypoint, ...], by_line: bool = False) -> list[tuple[int, int]]:
    """Indent mode holds at press points: a path runs in segments that end at each hold (and a long path, or
    one whose lines are followed, at each line's retract, where the arm stops anyway: planning hundreds of
    waypoints at once starves the node)."""
    segments = []
    start_i = 0
    long = by_line or len(waypoints) > 200  # e.g. sweep lines following a dome
    for c in [i for i, w in enumerate(waypoints) if w.hold_s > 0 or (long and w.kind == "retract")]:
        segments.append((start_i, c))
        start_i = c + 1
    if start_i < len(waypoints):
        segments.append((start_i, len(waypoints) - 1))
    return segments
