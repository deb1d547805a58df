"""Cartesian model of a UR-like arm: moveL paths with blends, stopL and speedL on a 500 Hz clock.

Pure model (no I/O), shared by the UR controller emulator and the simulated robot driver.

Units: positions in mm, speeds in mm/s, accelerations in mm/s^2, orientations as rotation
vectors (rad), angular speeds in rad/s. As on a UR controller, a move that only rotates the tool
reads its speed and acceleration as rad/s and rad/s^2 in the same numbers as m/s and m/s^2,
so inside the model 1 rad of rotation counts as 1000 mm of path.

Time advances in whole controller ticks of 2 ms (the e-Series control rate): `step(dt_s)`
accumulates wall time in integer nanoseconds and runs only whole ticks, so the state after a
given total time does not depend on how that time was split into calls. During a path the
state at tick k is a closed-form function of k, so long steps cost no more than short ones.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from enum import Enum

import numpy as np

from models.arm_path import (
    EPS_MM,
    MM_PER_RAD,
    ArmTarget,
    PathPlan,
    Pose,
    check_target,
    qmul,
    quat,
    quat_to_rotvec,
)

__all__ = ["TICK_S", "ArmModel", "ArmStatus", "ArmTarget", "Pose", "Twist"]

Twist = tuple[float, float, float, float, float, float]

TICK_S = 0.002
_TICK_NS = 2_000_000


class ArmStatus(Enum):
    """What the arm is doing: IDLE (never moved), MOVING, STOPPING (decelerating after stop_l),
    DONE (last motion completed), STOPPED (last motion cancelled by stop_l)."""

    IDLE = "idle"
    MOVING = "moving"
    STOPPING = "stopping"
    DONE = "done"
    STOPPED = "stopped"


class ArmModel:
    """A UR-like arm reduced to its tool centre point (TCP), moving in Cartesian space.

    Commands mirror URScript: `move_l`/`move_path` (trapezoidal moveL with blend radii),
    `stop_l` (decelerate along the path), `speed_l` (ramp to a tool velocity). Every commanded
    speed and acceleration is clamped to `max_speed_mm_s`/`max_accel_mm_s2`, and the planned
    motion never exceeds the (clamped) speed and acceleration of the segment it is on. A new
    path given while the arm moves is started after the arm has decelerated to rest.
    """

    def __init__(self, pose: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), *,
                 max_speed_mm_s: float = 1000.0, max_accel_mm_s2: float = 5000.0) -> None:
        for name, value in (("max_speed_mm_s", max_speed_mm_s), ("max_accel_mm_s2", max_accel_mm_s2)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ArmModel: {name} must be a finite number > 0, got {value!r}")
        self.max_speed_mm_s = float(max_speed_mm_s)
        self.max_accel_mm_s2 = float(max_accel_mm_s2)
        self._pose: Pose = _as_pose(pose, "ArmModel: pose")
        self._twist = np.zeros(6)
        self._ticks = 0
        self._ns = 0
        self._mode = "idle"  # idle | path | stop | speed
        self._status = ArmStatus.IDLE
        self._plan: PathPlan | None = None
        self._tick0 = 0
        self._stop = (0.0, 0.0, 1.0, 0.0)  # s0, v0, decel, duration of the active stop
        self._pending: list[ArmTarget] | None = None
        self._index = 0
        self._vel_target = np.zeros(6)
        self._vel_accel = 1.0
        self._vel_end: int | None = None
        self._vel_stopping = False
        self._rot = quat(self._pose[3:])

    # ----------------------------------------------------------------- state
    @property
    def pose(self) -> Pose:
        """TCP pose: x, y, z (mm) and rotation vector rx, ry, rz (rad)."""
        return self._pose

    @property
    def tcp_speed(self) -> Twist:
        """TCP velocity: vx, vy, vz (mm/s) and angular velocity wx, wy, wz (rad/s)."""
        return _as_tuple(self._twist)

    @property
    def path_index(self) -> int:
        """Index of the waypoint being approached (the last one once a path is done); as in
        UR's moveL paths, it advances when the arm enters the blend around a waypoint."""
        return self._index

    @property
    def status(self) -> ArmStatus:
        return self._status

    @property
    def done(self) -> bool:
        """True once the last commanded motion has completed (not cancelled)."""
        return self._status is ArmStatus.DONE

    @property
    def is_moving(self) -> bool:
        return self._mode != "idle"

    @property
    def ticks(self) -> int:
        return self._ticks

    @property
    def time_s(self) -> float:
        """Simulated time since construction (s), in whole 2 ms ticks."""
        return self._ticks * TICK_S

    def set_pose(self, pose: Sequence[float]) -> None:
        """Place the TCP at `pose` (mm, rad); only allowed while the arm is at rest."""
        if self.is_moving:
            raise RuntimeError("ArmModel.set_pose: the arm is moving; stop it first")
        self._pose = _as_pose(pose, "ArmModel.set_pose: pose")
        self._rot = quat(self._pose[3:])

    # -------------------------------------------------------------- commands
    def move_l(self, pose: Sequence[float], speed_mm_s: float, accel_mm_s2: float) -> None:
        """Linear move to `pose` (mm, rad) with a trapezoidal speed profile."""
        self.move_path([ArmTarget(_as_pose(pose, "move_l: pose"), speed_mm_s, accel_mm_s2)])

    def move_path(self, targets: Sequence[ArmTarget]) -> None:
        """Run a sequence of moveL waypoints, blending around each intermediate waypoint."""
        if not targets:
            raise ValueError("move_path: the path has no waypoints")
        capped = []
        for i, t in enumerate(targets):
            check_target(i, t)
            capped.append(ArmTarget(_as_pose(t.pose, f"waypoint {i}: pose"), min(t.speed_mm_s, self.max_speed_mm_s),
                                    min(t.accel_mm_s2, self.max_accel_mm_s2), t.blend_mm))
        if self._mode == "idle":
            self._start_plan(capped)
            return
        self._pending = capped
        self._begin_stop(capped[0].accel_mm_s2, keep_pending=True)

    def stop_l(self, decel_mm_s2: float) -> None:
        """Decelerate to rest at `decel_mm_s2` (raised if needed to stay within the path and
        its speed limits); cancels any pending path. No effect when the arm is at rest."""
        if not (math.isfinite(decel_mm_s2) and decel_mm_s2 > 0):
            raise ValueError(f"stop_l: decel_mm_s2 must be a finite number > 0, got {decel_mm_s2!r}")
        self._pending = None
        self._begin_stop(min(decel_mm_s2, self.max_accel_mm_s2), keep_pending=False)

    def speed_l(self, velocity: Sequence[float], accel_mm_s2: float, duration_s: float | None = None) -> None:
        """Ramp the TCP velocity to `velocity` (mm/s, rad/s) at `accel_mm_s2` and hold it, for
        `duration_s` seconds if given (then decelerate to rest) or until stop_l."""
        vel = np.asarray(velocity, float)
        if vel.shape != (6,) or not np.all(np.isfinite(vel)):
            raise ValueError(f"speed_l: velocity must be 6 finite numbers (mm/s, rad/s), got {velocity!r}")
        if not (math.isfinite(accel_mm_s2) and accel_mm_s2 > 0):
            raise ValueError(f"speed_l: accel_mm_s2 must be a finite number > 0, got {accel_mm_s2!r}")
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"speed_l: duration_s must be a finite number > 0 or None, got {duration_s!r}")
        for part, cap in ((slice(0, 3), self.max_speed_mm_s), (slice(3, 6), self.max_speed_mm_s / MM_PER_RAD)):
            norm = float(np.linalg.norm(vel[part]))
            if norm > cap:
                vel[part] *= cap / norm
        self._pending = None
        if self._mode != "speed":
            self._rot = quat(self._pose[3:])
        self._mode, self._status = "speed", ArmStatus.MOVING
        self._vel_target = vel
        self._vel_accel = min(accel_mm_s2, self.max_accel_mm_s2)
        self._vel_end = None if duration_s is None else self._ticks + max(1, math.ceil(duration_s / TICK_S - 1e-9))
        self._vel_stopping = False

    def step(self, dt_s: float) -> None:
        """Advance the simulated clock by dt_s seconds (whole 2 ms ticks; remainders carry over)."""
        if not (math.isfinite(dt_s) and dt_s >= 0):
            raise ValueError(f"ArmModel.step: dt_s must be a finite number >= 0, got {dt_s!r}")
        self.step_ns(round(dt_s * 1e9))

    def step_ns(self, dt_ns: int) -> None:
        """Advance the simulated clock by dt_ns nanoseconds (exact; remainders carry over)."""
        if dt_ns < 0:
            raise ValueError(f"ArmModel.step_ns: dt_ns must be >= 0, got {dt_ns}")
        n, self._ns = divmod(self._ns + int(dt_ns), _TICK_NS)
        self._advance(n)

    # -------------------------------------------------------------- internals
    def _start_plan(self, targets: list[ArmTarget]) -> None:
        self._pending = None
        plan = PathPlan(self._pose, targets)
        self._plan, self._tick0 = plan, self._ticks
        if not plan.prims:
            self._finish(plan.final_pose, ArmStatus.DONE, plan.count - 1)
            return
        self._mode, self._status = "path", ArmStatus.MOVING
        self._refresh()

    def _begin_stop(self, decel: float, keep_pending: bool) -> None:
        if self._mode == "speed":
            self._vel_target = np.zeros(6)
            self._vel_accel = max(decel, self._vel_accel) if keep_pending else decel
            self._vel_end = None
            self._vel_stopping = not keep_pending
            if not keep_pending:
                self._status = ArmStatus.STOPPING
            return
        if self._mode not in ("path", "stop") or self._plan is None:
            return
        s, v = self._sample()
        if self._mode == "stop" and keep_pending:
            decel = max(decel, self._stop[2])
        rem = self._plan.total - s
        need = [decel] + [(v * v - w * w) / (2 * d) for d, w in self._plan.speed_limit_ahead(s) if w < v and d > 0]
        need.append(v * v / (2 * rem) if rem > EPS_MM else math.inf)
        decel = max(need)
        self._stop = (s, v, decel, 0.0 if math.isinf(decel) else v / decel)
        self._mode, self._tick0 = "stop", self._ticks
        self._status = ArmStatus.MOVING if keep_pending else ArmStatus.STOPPING
        self._refresh()

    def _require_plan(self) -> PathPlan:
        if self._plan is None:
            raise RuntimeError(f"ArmModel: internal error, no plan in mode {self._mode!r}")
        return self._plan

    def _sample(self) -> tuple[float, float]:
        plan = self._require_plan()
        t = (self._ticks - self._tick0) * TICK_S
        if self._mode == "path":
            return plan.sample(t)
        s0, v0, d, dur = self._stop
        t = min(t, dur)
        return min(s0 + v0 * t - 0.5 * d * t * t, plan.total), max(v0 - d * t, 0.0)

    def _refresh(self) -> None:
        s, v = self._sample()
        prim, u = self._require_plan().locate(s)
        self._pose = prim.pose_at(u)
        self._twist = prim.twist6_per_mm(u) * v
        self._index = prim.index

    def _finish(self, pose: Pose, status: ArmStatus, index: int | None = None) -> None:
        self._pose, self._twist, self._mode, self._status = pose, np.zeros(6), "idle", status
        self._rot = quat(pose[3:])
        if index is not None:
            self._index = index
        if self._pending is not None:
            self._start_plan(self._pending)

    def _advance(self, n: int) -> None:
        while n > 0:
            if self._mode in ("path", "stop"):
                plan = self._require_plan()
                dur = plan.duration if self._mode == "path" else self._stop[3]
                end = self._tick0 + max(0, math.ceil(dur / TICK_S - 1e-9))
                if self._ticks + n < end:
                    self._ticks += n
                    self._refresh()
                    return
                n -= max(0, end - self._ticks)
                self._ticks = max(self._ticks, end)
                if self._mode == "path":
                    self._finish(plan.final_pose, ArmStatus.DONE, plan.count - 1)
                else:
                    self._refresh()
                    self._finish(self._pose, ArmStatus.STOPPED)
            elif self._mode == "speed":
                self._speed_tick()
                self._ticks += 1
                n -= 1
            else:
                self._ticks += n
                return

    def _speed_tick(self) -> None:
        old = self._twist.copy()
        new = old.copy()
        for part, dv_max in ((slice(0, 3), self._vel_accel * TICK_S), (slice(3, 6), self._vel_accel * TICK_S / MM_PER_RAD)):
            dv = self._vel_target[part] - old[part]
            norm = float(np.linalg.norm(dv))
            new[part] = self._vel_target[part] if norm <= dv_max else old[part] + dv * (dv_max / norm)
        mean = 0.5 * (old + new)
        pos = np.asarray(self._pose[:3]) + mean[:3] * TICK_S
        rotvec = np.asarray(self._pose[3:])
        if np.any(mean[3:]):
            self._rot = qmul(quat(mean[3:] * TICK_S), self._rot)
            rotvec = quat_to_rotvec(self._rot)
        self._twist = new
        self._pose = _as_tuple(np.concatenate((pos, rotvec)))
        if self._vel_end is not None and self._ticks + 1 >= self._vel_end:
            self._vel_target, self._vel_end = np.zeros(6), None
        if not np.any(self._vel_target) and not np.any(new):
            self._finish(self._pose, ArmStatus.STOPPED if self._vel_stopping else ArmStatus.DONE)


def _as_tuple(values: np.ndarray) -> Pose:
    a = np.asarray(values, dtype=float).tolist()  # Python floats of the same values, in one call (every 2 ms)
    return (a[0], a[1], a[2], a[3], a[4], a[5])


def _as_pose(values: Sequence[float], what: str) -> Pose:
    if len(values) != 6 or not all(math.isfinite(float(v)) for v in values):
        raise ValueError(f"{what} must be 6 finite numbers (x, y, z mm, rx, ry, rz rad), got {values!r}")
    return _as_tuple(np.asarray(values, float))
