"""Simulated robot driver: the kinematic arm of models.arm, in the phantom frame.

The arm is advanced lazily, on every call, to the simulated time
``(clock() - t_connect) * time_scale``: time_scale 10 runs it ten times faster than the
clock. The arm moves in whole 2 ms ticks computed from that absolute time, so a run is
deterministic for a given sequence of clock readings however often it is polled; pass a
controllable clock (e.g. palpa's MockClock.now_ns) to step it by hand in tests. The sim
reports no contact force (the probe drivers simulate the tissue).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from models.arm import ArmModel, ArmStatus, ArmTarget
from nodes.drivers.host_clock import host_ns
from nodes.drivers.robot import (
    MotionStatus,
    PathPointLike,
    PathProgress,
    RobotConnectionError,
    RobotDriverError,
    TcpState,
    Vec6,
    checked_path,
)

__all__ = ["SimRobotDriver"]

_LATCHED = (MotionStatus.PROTECTIVE_STOP, MotionStatus.DISCONNECTED, MotionStatus.FAULT)


class SimRobotDriver:
    """RobotDriver on a simulated arm starting at `home_mm` (x, y, z in the phantom frame)
    with the tool held at `tool_rotvec`. Speeds and accelerations above the caps are refused
    by move_path (ValueError), as the real driver does."""

    def __init__(self, home_mm: Sequence[float] = (0.0, 0.0, 40.0), *,
                 tool_rotvec: Sequence[float] = (0.0, math.pi, 0.0), time_scale: float = 1.0,
                 clock: Callable[[], int] | None = None, max_speed_mm_s: float = 250.0,
                 max_accel_mm_s2: float = 2500.0) -> None:
        if len(home_mm) != 3 or len(tool_rotvec) != 3:
            raise ValueError(f"SimRobotDriver: home_mm and tool_rotvec need 3 numbers each, got {home_mm!r}, {tool_rotvec!r}")
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ValueError(f"SimRobotDriver: time_scale must be a finite number > 0, got {time_scale!r}")
        self.tool_rotvec = (float(tool_rotvec[0]), float(tool_rotvec[1]), float(tool_rotvec[2]))
        self.time_scale = float(time_scale)
        self.max_speed_mm_s, self.max_accel_mm_s2 = float(max_speed_mm_s), float(max_accel_mm_s2)
        self._clock = clock or host_ns
        self.arm = ArmModel((*(float(v) for v in home_mm), *self.tool_rotvec),
                            max_speed_mm_s=max_speed_mm_s, max_accel_mm_s2=max_accel_mm_s2)
        self._t0: int | None = None
        self._sim_ns = 0  # simulated time already given to the arm
        self._now = 0
        self._count = 0
        self._status = MotionStatus.IDLE
        self._message = ""

    # ---------------------------------------------------------------- driver
    def connect(self) -> None:
        now = self._clock()
        if self._t0 is None:  # first connect, or again after close(): simulated time carries on
            self._t0, self._now = now - round(self._sim_ns / self.time_scale), now
        else:
            self._advance()
        if self._status in _LATCHED:
            if self.arm.is_moving:
                raise RobotConnectionError("sim arm: still decelerating after the fault; connect() again in a moment")
            self._status, self._message = MotionStatus.IDLE, ""

    def state(self) -> TcpState:
        self._advance()
        return TcpState(self._now, self.arm.pose, self.arm.tcp_speed, (0.0,) * 6)

    def move_path(self, points: Sequence[PathPointLike]) -> None:
        self._require_connected()
        path = checked_path(points, self.max_speed_mm_s, self.max_accel_mm_s2, self.arm.pose[:3])
        if self._status in _LATCHED:
            raise RobotDriverError(f"sim arm: cannot move: {self._status.value}: {self._message}")
        self._advance()
        self.arm.move_path([ArmTarget((p.x_mm, p.y_mm, p.z_mm, *self.tool_rotvec), p.speed_mm_s,
                                      p.accel_mm_s2, p.blend_mm) for p in path])
        self._count = len(path)
        self._status, self._message = MotionStatus.MOVING, ""

    def progress(self) -> PathProgress:
        self._advance()
        if self._status in (MotionStatus.MOVING, MotionStatus.STOPPED):
            arm = self.arm.status
            if arm is ArmStatus.DONE:
                self._status = MotionStatus.DONE
            elif arm is ArmStatus.STOPPED and self._status is MotionStatus.STOPPED:
                self._message = "stopped by request; at rest"
        return PathProgress(self._status, self.arm.path_index if self._count else 0, self._message)

    def stop(self, decel_mm_s2: float) -> None:
        if self._t0 is None:
            return
        self._advance()
        if self.arm.is_moving:
            decel = decel_mm_s2 if math.isfinite(decel_mm_s2) and decel_mm_s2 > 0 else self.max_accel_mm_s2
            self.arm.stop_l(decel)
            if self._status is MotionStatus.MOVING:
                self._status, self._message = MotionStatus.STOPPED, f"stopped by request (decelerating at {decel:g} mm/s^2)"

    def close(self) -> None:
        self.stop(self.max_accel_mm_s2)
        self._t0 = None

    # ------------------------------------------------------------------ tests
    def inject_fault(self, status: MotionStatus, message: str) -> None:
        """Make the sim behave as if the robot reported `status` (PROTECTIVE_STOP,
        DISCONNECTED or FAULT): the arm stops at its maximum deceleration and the status is
        latched until connect(). For testing the scanner's reactions."""
        if status not in _LATCHED:
            raise ValueError(f"inject_fault: status must be one of {[s.name for s in _LATCHED]}, got {status.name}")
        self._advance()
        if self.arm.is_moving:
            self.arm.stop_l(self.max_accel_mm_s2)
        self._status, self._message = status, message

    # -------------------------------------------------------------- internals
    def _require_connected(self) -> None:
        if self._t0 is None:
            raise RobotDriverError("sim arm: not connected; call connect() first")

    def _advance(self) -> None:
        if self._t0 is None:
            return
        now = self._clock()
        if now <= self._now:
            return
        self._now = now
        target = round((now - self._t0) * self.time_scale)
        if target > self._sim_ns:
            self.arm.step_ns(target - self._sim_ns)
            self._sim_ns = target

    @property
    def pose(self) -> Vec6:
        """Current pose without advancing time (for tests)."""
        return self.arm.pose
