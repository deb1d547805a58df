"""Robot-side messages: TCP pose, the scan plan, scan status, e-stop."""

from __future__ import annotations

from typing import Literal

import msgspec

from palpa.message import Finite, Message


class RobotPose(Message, frozen=True, kw_only=True):
    """TCP pose in the phantom frame (topic ``robot/pose``): position in mm, rotation vector in rad."""

    stamp_ns: int
    x_mm: Finite
    y_mm: Finite
    z_mm: Finite
    rx_rad: Finite = 0.0
    ry_rad: Finite = 0.0
    rz_rad: Finite = 0.0
    speed_mm_s: Finite = 0.0
    force_z_n: Finite = 0.0


WaypointKind = Literal["approach", "contact", "press", "hold", "lift", "retract", "transit"]
"""What a waypoint is for (models.raster plans them); on the wire a plain string."""
ScanState = Literal["planning", "waiting", "idle", "touching", "approach", "scanning", "probing", "paused", "done",
                    "stopped", "fault", "estop"]
"""The scanner's states (``robot/scan_status``); on the wire a plain string."""


class PlanWaypoint(msgspec.Struct, frozen=True, kw_only=True):
    """One waypoint of a scan plan (phantom frame, mm)."""

    x_mm: Finite
    y_mm: Finite
    z_mm: Finite
    speed_mm_s: Finite
    kind: WaypointKind
    line: int
    hold_s: Finite = 0.0


class ScanPlan(Message, frozen=True, kw_only=True):
    """The whole raster path, published latched on ``robot/plan`` before any motion."""

    stamp_ns: int
    mode: str
    """``sweep`` or ``indent``."""
    region_mm: tuple[Finite, Finite, Finite, Finite]
    """x0, y0, x1, y1."""
    spacing_mm: Finite
    speed_mm_s: Finite
    lines: int
    estimated_duration_s: Finite
    waypoints: list[PlanWaypoint]


class TableHeight(Message, frozen=True, kw_only=True):
    """The table's height beside the specimen as the probe touched it (topic ``scanner/table``, latched): what the
    estimator's ``thickness: probe`` counts the layer's thickness from. Published by the scanner's table touch
    (``table_point_mm``) before its touch-off; without one, the table is z = 0 of the phantom frame."""

    stamp_ns: int
    x_mm: Finite
    y_mm: Finite
    z_mm: Finite


class ScanStatus(Message, frozen=True, kw_only=True):
    """Scan progress (topic ``robot/scan_status``)."""

    stamp_ns: int
    state: ScanState
    line: int
    lines: int
    progress: Finite
    """0..1 of the planned path length."""
    eta_s: Finite
    message: str = ""


class EStop(Message, frozen=True, kw_only=True):
    """Emergency stop (topic ``robot/estop``): ``engaged`` stops the arm at once."""

    stamp_ns: int
    engaged: bool = True
    reason: str = ""
