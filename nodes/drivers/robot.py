"""Robot driver interface for the robot scanner node, and the checks both drivers share.

Frame: every pose a driver takes or returns is in the phantom frame (mm, origin at a phantom
corner, z up); orientations are rotation vectors (rad). A driver owns the conversion to its
robot's own frame and units (the ur_rtde driver: robot base frame, metres).

Two drivers implement it: ``robot_sim.SimRobotDriver`` (the kinematic arm model of
``models.arm``) and ``robot_urrtde.URRtdeDriver`` (a Universal Robots arm through ur_rtde).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Protocol, runtime_checkable

__all__ = [
    "MotionStatus",
    "PathPoint",
    "PathPointLike",
    "PathProgress",
    "RobotConnectionError",
    "RobotDriver",
    "RobotDriverError",
    "TcpState",
    "Vec6",
    "checked_path",
]

Vec6 = tuple[float, float, float, float, float, float]


class RobotDriverError(Exception):
    """A robot command could not be carried out (the message says why and what to do)."""


class RobotConnectionError(RobotDriverError):
    """The robot could not be reached or refuses to be driven remotely."""


@dataclass(frozen=True)
class TcpState:
    """Latest tool centre point state.

    stamp_ns: when it was read (the driver's clock, ns since the Unix epoch by default);
    pose: x, y, z (mm), rx, ry, rz (rad); speed_mm_s: vx, vy, vz (mm/s), wx, wy, wz (rad/s);
    force_n: Fx, Fy, Fz (N), Tx, Ty, Tz (N m) acting on the tool.
    """

    stamp_ns: int
    pose: Vec6
    speed_mm_s: Vec6
    force_n: Vec6


class MotionStatus(Enum):
    """State of the last commanded path.

    IDLE: nothing commanded since connect; MOVING: on its way; DONE: reached the last
    waypoint; STOPPED: stopped by ``stop()`` (or decelerating to rest after it);
    PROTECTIVE_STOP: the robot's safety system stopped it; DISCONNECTED: the link to the
    robot is lost; FAULT: anything else that ended the motion. The last three are latched
    until ``connect()`` is called again.
    """

    IDLE = "idle"
    MOVING = "moving"
    DONE = "done"
    PROTECTIVE_STOP = "protective_stop"
    STOPPED = "stopped"
    DISCONNECTED = "disconnected"
    FAULT = "fault"


@dataclass(frozen=True)
class PathProgress:
    """Progress of the last path: index of the waypoint reached or being approached (the last
    one when DONE), and a message that says what happened for STOPPED and the latched states."""

    status: MotionStatus
    index: int
    message: str = ""


@runtime_checkable
class PathPointLike(Protocol):
    """A waypoint: target position (mm, phantom frame), speed (mm/s) and acceleration (mm/s^2)
    of the move that ends there, blend radius (mm) through it. models.raster.Waypoint fits."""

    @property
    def x_mm(self) -> float: ...
    @property
    def y_mm(self) -> float: ...
    @property
    def z_mm(self) -> float: ...
    @property
    def speed_mm_s(self) -> float: ...
    @property
    def accel_mm_s2(self) -> float: ...
    @property
    def blend_mm(self) -> float: ...


@dataclass(frozen=True)
class PathPoint:
    """A plain PathPointLike."""

    x_mm: float
    y_mm: float
    z_mm: float
    speed_mm_s: float
    accel_mm_s2: float
    blend_mm: float = 0.0


class RobotDriver(Protocol):
    """What the robot scanner node needs from an arm. Paths run asynchronously."""

    def connect(self) -> None:
        """Connect (again): clears a latched PROTECTIVE_STOP/DISCONNECTED/FAULT if the robot
        is usable; raises RobotConnectionError with the reason otherwise."""
        ...

    def state(self) -> TcpState:
        """Latest TCP state (phantom frame)."""
        ...

    def move_path(self, points: Sequence[PathPointLike]) -> None:
        """Start moving through `points` with linear moves; returns once the motion started.
        Raises ValueError for an invalid path, RobotDriverError if the robot cannot move."""
        ...

    def progress(self) -> PathProgress:
        """Status of the last path."""
        ...

    def stop(self, decel_mm_s2: float) -> None:
        """Decelerate to rest along the path (stopL); returns at once, never raises."""
        ...

    def close(self) -> None:
        """Stop any motion and release the robot."""
        ...


def checked_path(points: Sequence[PathPointLike], max_speed_mm_s: float, max_accel_mm_s2: float,
                 start_mm: tuple[float, float, float] | None = None) -> list[PathPoint]:
    """Validate a path and return it as PathPoints with usable blends: finite coordinates,
    0 < speed <= max_speed_mm_s, 0 < accel <= max_accel_mm_s2, blend >= 0. Blends are clipped
    to half of each adjacent segment (a UR controller rejects overlapping blends; `start_mm`,
    the current position, bounds the first one) and the last waypoint never blends. Raises
    ValueError naming the first bad waypoint."""
    if not points:
        raise ValueError("move_path: the path has no waypoints")
    out: list[PathPoint] = []
    for i, p in enumerate(points):
        xyz = (p.x_mm, p.y_mm, p.z_mm)
        if not all(math.isfinite(v) for v in xyz):
            raise ValueError(f"move_path: waypoint {i}: position must be finite, got {xyz}")
        if not (math.isfinite(p.speed_mm_s) and 0 < p.speed_mm_s <= max_speed_mm_s):
            raise ValueError(f"move_path: waypoint {i}: speed_mm_s must be in (0, {max_speed_mm_s:g}], got {p.speed_mm_s!r}")
        if not (math.isfinite(p.accel_mm_s2) and 0 < p.accel_mm_s2 <= max_accel_mm_s2):
            raise ValueError(f"move_path: waypoint {i}: accel_mm_s2 must be in (0, {max_accel_mm_s2:g}], got {p.accel_mm_s2!r}")
        if not (math.isfinite(p.blend_mm) and p.blend_mm >= 0):
            raise ValueError(f"move_path: waypoint {i}: blend_mm must be >= 0, got {p.blend_mm!r}")
        out.append(PathPoint(float(p.x_mm), float(p.y_mm), float(p.z_mm), float(p.speed_mm_s),
                             float(p.accel_mm_s2), float(p.blend_mm)))
    for i, p in enumerate(out):
        if i == len(out) - 1:
            blend = 0.0
        else:
            nxt = out[i + 1]
            prev = (out[i - 1].x_mm, out[i - 1].y_mm, out[i - 1].z_mm) if i > 0 else start_mm
            seg_in = math.dist(prev, (p.x_mm, p.y_mm, p.z_mm)) if prev is not None else math.inf
            seg_out = math.dist((p.x_mm, p.y_mm, p.z_mm), (nxt.x_mm, nxt.y_mm, nxt.z_mm))
            blend = min(p.blend_mm, 0.5 * seg_in, 0.5 * seg_out)
        if blend != p.blend_mm:
            out[i] = PathPoint(p.x_mm, p.y_mm, p.z_mm, p.speed_mm_s, p.accel_mm_s2, blend)
    return out
