"""Robot-side messages: TCP pose, the scan plan, scan status, e-stop."""

from __future__ import annotations

import msgspec

from palpa.message import Message


class RobotPose(Message, frozen=True, kw_only=True):
    """TCP pose in the phantom frame (topic ``robot/pose``): position in mm, rotation vector in rad."""

    stamp_ns: int
    x_mm: float
    y_mm: float
    z_mm: float
    rx_rad: float = 0.0
    ry_rad: float = 0.0
    rz_rad: float = 0.0
    speed_mm_s: float = 0.0
    force_z_n: float = 0.0


class PlanWaypoint(msgspec.Struct, frozen=True, kw_only=True):
    """One waypoint of a scan plan (phantom frame, mm)."""

    x_mm: float
    y_mm: float
    z_mm: float
    speed_mm_s: float
    kind: str
    """``approach``, ``contact``, ``press``, ``hold``, ``lift``, ``retract``, ``transit``."""
    line: int
    hold_s: float = 0.0


class ScanPlan(Message, frozen=True, kw_only=True):
    """The whole raster path, published latched on ``robot/plan`` before any motion."""

    stamp_ns: int
    mode: str
    """``sweep`` or ``indent``."""
    region_mm: tuple[float, float, float, float]
    """x0, y0, x1, y1."""
    spacing_mm: float
    speed_mm_s: float
    lines: int
    estimated_duration_s: float
    waypoints: list[PlanWaypoint]


class ScanStatus(Message, frozen=True, kw_only=True):
    """Scan progress (topic ``robot/scan_status``)."""

    stamp_ns: int
    state: str
    """``planning``, ``approach``, ``scanning``, ``done``, ``stopped``, ``fault``, ``estop``."""
    line: int
    lines: int
    progress: float
    """0..1 of the planned path length."""
    eta_s: float
    message: str = ""


class EStop(Message, frozen=True, kw_only=True):
    """Emergency stop (topic ``robot/estop``): ``engaged`` stops the arm at once."""

    stamp_ns: int
    engaged: bool = True
    reason: str = ""
