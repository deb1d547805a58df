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

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

Pose = tuple[float, float, float, float, float, float]
Twist = tuple[float, float, float, float, float, float]

TICK_S = 0.002
_TICK_NS = 2_000_000
_MM_PER_RAD = 1000.0  # path length that one radian of pure tool rotation counts as
_EPS_MM = 1e-9
_MIN_BLEND_MM = 1e-6  # blends below this are treated as none
_MIN_BLEND_SPEED_FRACTION = 0.2  # blends slower than this fraction of the path speed become stops
_BEZIER_SAMPLES = 65


def _quat(rotvec: np.ndarray | Sequence[float]) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation vector."""
    v = np.asarray(rotvec, float)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.array([1.0, 0.5 * v[0], 0.5 * v[1], 0.5 * v[2]])
    return np.concatenate(([math.cos(angle / 2)], v * (math.sin(angle / 2) / angle)))


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion of rotation a applied after rotation b."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (angle <= pi) of a quaternion."""
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-12:
        return np.asarray(2.0 * q[1:], float)
    return np.asarray(q[1:] * (2.0 * math.atan2(s, q[0]) / s), float)


def _turn(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Rotation vector taking orientation q0 to q1 (in the base frame)."""
    return _rotvec(_qmul(q1, q0 * np.array([1.0, -1.0, -1.0, -1.0])))


class ArmStatus(Enum):
    """What the arm is doing: IDLE (never moved), MOVING, STOPPING (decelerating after stop_l),
    DONE (last motion completed), STOPPED (last motion cancelled by stop_l)."""

    IDLE = "idle"
    MOVING = "moving"
    STOPPING = "stopping"
    DONE = "done"
    STOPPED = "stopped"


@dataclass(frozen=True)
class ArmTarget:
    """One moveL waypoint: pose (mm, rad), tool speed (mm/s), acceleration (mm/s^2), and the
    blend radius (mm) around this waypoint (ignored on the last waypoint of a path)."""

    pose: Pose
    speed_mm_s: float
    accel_mm_s2: float
    blend_mm: float = 0.0


def _check_target(i: int, t: ArmTarget) -> None:
    if len(t.pose) != 6 or not all(math.isfinite(v) for v in t.pose):
        raise ValueError(f"waypoint {i}: pose must be 6 finite numbers (x, y, z mm, rx, ry, rz rad), got {t.pose!r}")
    for name, value, lo in (("speed_mm_s", t.speed_mm_s, 0.0), ("accel_mm_s2", t.accel_mm_s2, 0.0)):
        if not (math.isfinite(value) and value > lo):
            raise ValueError(f"waypoint {i}: {name} must be a finite number > 0, got {value!r}")
    if not (math.isfinite(t.blend_mm) and t.blend_mm >= 0.0):
        raise ValueError(f"waypoint {i}: blend_mm must be a finite number >= 0, got {t.blend_mm!r}")


class _Primitive:
    """A piece of path parametrised by length u in [0, length]: a line, a pure rotation, or a
    quadratic Bezier blend. Orientation is slerped linearly in u from rot0 to rot1."""

    def __init__(self, p0: np.ndarray, p1: np.ndarray, rot0: np.ndarray, rot1: np.ndarray,
                 vmax: float, accel: float, index: int, ctrl: np.ndarray | None = None,
                 rotvec0: np.ndarray | None = None) -> None:
        self.p0, self.p1, self.ctrl, self.rot0 = p0, p1, ctrl, rot0
        self.rotvec0 = _rotvec(rot0) if rotvec0 is None else rotvec0
        self.dw = _turn(rot0, rot1)  # rotation to apply over the whole primitive
        self.accel, self.index = accel, index
        angle_mm = float(np.linalg.norm(self.dw)) * _MM_PER_RAD
        if ctrl is None:
            self.lin = float(np.linalg.norm(p1 - p0))
            self.length = self.lin if self.lin > _EPS_MM else angle_mm
            self.vmax = vmax
        else:
            tau = np.linspace(0.0, 1.0, _BEZIER_SAMPLES)
            pts = np.outer((1 - tau) ** 2, p0) + np.outer(2 * (1 - tau) * tau, ctrl) + np.outer(tau**2, p1)
            self._cum = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))))
            self._tau = tau
            self.lin = self.length = float(self._cum[-1])
            d1, d2 = 2 * (1 - tau)[:, None] * (ctrl - p0) + 2 * tau[:, None] * (p1 - ctrl), 2 * (p1 - 2 * ctrl + p0)
            cross = np.linalg.norm(np.cross(d1, d2), axis=1)
            speed = np.linalg.norm(d1, axis=1)
            rho = float(np.min(speed**3 / np.maximum(cross, 1e-300)))
            # keep the centripetal acceleration v^2/rho within the commanded acceleration
            self.vmax = min(vmax, math.sqrt(accel * rho))

    def _tau_of(self, u: float) -> float:
        return float(np.interp(u, self._cum, self._tau))

    def position(self, u: float) -> np.ndarray:
        if self.ctrl is None:
            if self.lin <= _EPS_MM:
                return self.p0
            return np.asarray(self.p0 + (self.p1 - self.p0) * (u / self.length), float)
        t = self._tau_of(u)
        return np.asarray((1 - t) ** 2 * self.p0 + 2 * (1 - t) * t * self.ctrl + t**2 * self.p1, float)

    def rotvec(self, u: float) -> np.ndarray:
        if not np.any(self.dw):
            return self.rotvec0
        return _rotvec(_qmul(_quat(self.dw * (u / self.length)), self.rot0))

    def twist_per_mm(self, u: float) -> tuple[np.ndarray, np.ndarray]:
        """(linear direction, angular rate) per mm of path at u."""
        ang = self.dw / self.length
        if self.ctrl is None:
            lin = (self.p1 - self.p0) / self.length if self.lin > _EPS_MM else np.zeros(3)
            return lin, ang
        t = self._tau_of(u)
        d = 2 * (1 - t) * (self.ctrl - self.p0) + 2 * t * (self.p1 - self.ctrl)
        return d / max(float(np.linalg.norm(d)), 1e-300), ang


@dataclass(frozen=True)
class _Trapezoid:
    """Speed along one primitive: from entry speed u0 up to vp, cruise, down to exit speed u1."""

    length: float
    u0: float
    u1: float
    vp: float
    accel: float

    @property
    def t_acc(self) -> float:
        return (self.vp - self.u0) / self.accel

    @property
    def t_dec(self) -> float:
        return (self.vp - self.u1) / self.accel

    @property
    def d_cruise(self) -> float:
        d_acc = (self.vp**2 - self.u0**2) / (2 * self.accel)
        d_dec = (self.vp**2 - self.u1**2) / (2 * self.accel)
        return max(0.0, self.length - d_acc - d_dec)

    @property
    def duration(self) -> float:
        return self.t_acc + self.d_cruise / self.vp + self.t_dec

    def sample(self, t: float) -> tuple[float, float]:
        a, t_acc, t_cru = self.accel, self.t_acc, self.d_cruise / self.vp
        if t <= t_acc:
            return self.u0 * t + 0.5 * a * t * t, self.u0 + a * t
        d_acc = (self.vp**2 - self.u0**2) / (2 * a)
        if t <= t_acc + t_cru:
            return d_acc + self.vp * (t - t_acc), self.vp
        tau = min(t - t_acc - t_cru, self.t_dec)
        s = d_acc + self.d_cruise + self.vp * tau - 0.5 * a * tau * tau
        return min(s, self.length), max(self.vp - a * tau, self.u1)


class _Plan:
    """Geometry and time-optimal speed profile of one moveL path started from rest."""

    def __init__(self, start: Pose, targets: Sequence[ArmTarget]) -> None:
        self.final_pose = targets[-1].pose
        self.count = len(targets)
        pts = [np.asarray(start[:3], float)] + [np.asarray(t.pose[:3], float) for t in targets]
        rvs = [np.asarray(start[3:], float)] + [np.asarray(t.pose[3:], float) for t in targets]
        rots = [_quat(r) for r in rvs]
        seg_len = [float(np.linalg.norm(pts[i + 1] - pts[i])) for i in range(len(targets))]
        # effective blend radius at waypoint i (between segment i and i+1); blends never overlap
        blend = [0.0] * len(targets)
        for i in range(len(targets) - 1):
            if seg_len[i] <= _EPS_MM or seg_len[i + 1] <= _EPS_MM:
                continue
            r = min(targets[i].blend_mm, 0.5 * seg_len[i], 0.5 * seg_len[i + 1])
            cos_turn = float(np.dot(pts[i + 1] - pts[i], pts[i + 2] - pts[i + 1])) / (seg_len[i] * seg_len[i + 1])
            half = 0.5 * math.acos(min(1.0, max(-1.0, cos_turn)))
            # tightest radius of the blend curve: r cos^2(turn/2) / sin(turn/2); a blend the arm
            # would crawl through (near reversals) is replaced by a stop at the waypoint
            rho = r * math.cos(half) ** 2 / max(math.sin(half), 1e-12)
            v_min = min(targets[i].speed_mm_s, targets[i + 1].speed_mm_s)
            a_min = min(targets[i].accel_mm_s2, targets[i + 1].accel_mm_s2)
            if r >= _MIN_BLEND_MM and math.sqrt(a_min * rho) >= _MIN_BLEND_SPEED_FRACTION * v_min:
                blend[i] = r
        prims: list[_Primitive] = []
        smooth: list[bool] = []  # smooth[k]: junction before primitive k is tangent-continuous

        def at(i: int, frac: float) -> tuple[np.ndarray, np.ndarray]:
            """Position and orientation at fraction frac of segment i (waypoint i-1 -> i)."""
            return pts[i] + (pts[i + 1] - pts[i]) * frac, _qmul(_quat(_turn(rots[i], rots[i + 1]) * frac), rots[i])

        for i, tgt in enumerate(targets):
            v, a = tgt.speed_mm_s, tgt.accel_mm_s2
            f0 = blend[i - 1] / seg_len[i] if i > 0 and blend[i - 1] > 0 else 0.0
            f1 = 1.0 - blend[i] / seg_len[i] if blend[i] > 0 else 1.0
            p_a, r_a = at(i, f0)
            p_b, r_b = at(i, f1)
            rv0 = rvs[i] if f0 == 0.0 else None
            line = _Primitive(p_a, p_b, r_a, r_b, v, a, i, rotvec0=rv0)
            if line.length > _EPS_MM:
                prev_dir = prims[-1].twist_per_mm(prims[-1].length)[0] if prims else None
                this_dir = line.twist_per_mm(0.0)[0]
                smooth.append(prev_dir is not None and line.lin > _EPS_MM
                              and float(np.dot(prev_dir, this_dir)) > 1.0 - 1e-9)
                prims.append(line)
            if blend[i] > 0:
                nxt = targets[i + 1]
                q0, q1 = at(i + 1, blend[i] / seg_len[i + 1])
                curve = _Primitive(p_b, q0, r_b, q1, min(v, nxt.speed_mm_s),
                                   min(a, nxt.accel_mm_s2), i + 1, ctrl=pts[i + 1])
                if curve.length > _EPS_MM:
                    prims.append(curve)
                    smooth.append(True)
        self.prims = prims
        self.starts = [0.0]
        for p in prims:
            self.starts.append(self.starts[-1] + p.length)
        self.total = self.starts[-1]
        n = len(prims)
        w = [0.0] * (n + 1)  # junction speeds
        for k in range(1, n):
            w[k] = min(prims[k - 1].vmax, prims[k].vmax) if smooth[k] else 0.0
        for k in range(n - 1, 0, -1):
            w[k] = min(w[k], math.sqrt(w[k + 1] ** 2 + 2 * prims[k].accel * prims[k].length))
        for k in range(1, n):
            w[k] = min(w[k], math.sqrt(w[k - 1] ** 2 + 2 * prims[k - 1].accel * prims[k - 1].length))
        self.traps: list[_Trapezoid] = []
        self.t_starts = [0.0]
        for k, p in enumerate(prims):
            peak = math.sqrt((2 * p.accel * p.length + w[k] ** 2 + w[k + 1] ** 2) / 2)
            trap = _Trapezoid(p.length, w[k], w[k + 1], max(min(p.vmax, peak), w[k], w[k + 1]), p.accel)
            self.traps.append(trap)
            self.t_starts.append(self.t_starts[-1] + trap.duration)
        self.duration = self.t_starts[-1]

    def sample(self, t: float) -> tuple[float, float]:
        """Path length (mm) and path speed (mm/s) at time t (s) after the start."""
        if t >= self.duration or not self.traps:
            return self.total, 0.0
        k = bisect.bisect_right(self.t_starts, t) - 1
        s, v = self.traps[k].sample(t - self.t_starts[k])
        return self.starts[k] + s, v

    def locate(self, s: float) -> tuple[_Primitive, float]:
        k = min(max(bisect.bisect_right(self.starts, s) - 1, 0), len(self.prims) - 1)
        return self.prims[k], min(max(s - self.starts[k], 0.0), self.prims[k].length)

    def speed_limit_ahead(self, s: float) -> list[tuple[float, float]]:
        """(distance ahead, speed limit) at every junction and primitive start after s."""
        return [(self.starts[k] - s, self.prims[k].vmax) for k in range(len(self.prims)) if self.starts[k] > s]


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
        self._plan: _Plan | None = None
        self._tick0 = 0
        self._stop = (0.0, 0.0, 1.0, 0.0)  # s0, v0, decel, duration of the active stop
        self._pending: list[ArmTarget] | None = None
        self._index = 0
        self._vel_target = np.zeros(6)
        self._vel_accel = 1.0
        self._vel_end: int | None = None
        self._vel_stopping = False
        self._rot = _quat(self._pose[3:])

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
        self._rot = _quat(self._pose[3:])

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
            _check_target(i, t)
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
        for part, cap in ((slice(0, 3), self.max_speed_mm_s), (slice(3, 6), self.max_speed_mm_s / _MM_PER_RAD)):
            norm = float(np.linalg.norm(vel[part]))
            if norm > cap:
                vel[part] *= cap / norm
        self._pending = None
        if self._mode != "speed":
            self._rot = _quat(self._pose[3:])
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
        plan = _Plan(self._pose, targets)
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
        need.append(v * v / (2 * rem) if rem > _EPS_MM else math.inf)
        decel = max(need)
        self._stop = (s, v, decel, 0.0 if math.isinf(decel) else v / decel)
        self._mode, self._tick0 = "stop", self._ticks
        self._status = ArmStatus.MOVING if keep_pending else ArmStatus.STOPPING
        self._refresh()

    def _require_plan(self) -> _Plan:
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
        lin, ang = prim.twist_per_mm(u)
        self._pose = _as_tuple(np.concatenate((prim.position(u), prim.rotvec(u))))
        self._twist = np.concatenate((lin * v, ang * v))
        self._index = prim.index

    def _finish(self, pose: Pose, status: ArmStatus, index: int | None = None) -> None:
        self._pose, self._twist, self._mode, self._status = pose, np.zeros(6), "idle", status
        self._rot = _quat(pose[3:])
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
        for part, dv_max in ((slice(0, 3), self._vel_accel * TICK_S), (slice(3, 6), self._vel_accel * TICK_S / _MM_PER_RAD)):
            dv = self._vel_target[part] - old[part]
            norm = float(np.linalg.norm(dv))
            new[part] = self._vel_target[part] if norm <= dv_max else old[part] + dv * (dv_max / norm)
        mean = 0.5 * (old + new)
        pos = np.asarray(self._pose[:3]) + mean[:3] * TICK_S
        rotvec = np.asarray(self._pose[3:])
        if np.any(mean[3:]):
            self._rot = _qmul(_quat(mean[3:] * TICK_S), self._rot)
            rotvec = _rotvec(self._rot)
        self._twist = new
        self._pose = _as_tuple(np.concatenate((pos, rotvec)))
        if self._vel_end is not None and self._ticks + 1 >= self._vel_end:
            self._vel_target, self._vel_end = np.zeros(6), None
        if not np.any(self._vel_target) and not np.any(new):
            self._finish(self._pose, ArmStatus.STOPPED if self._vel_stopping else ArmStatus.DONE)


def _as_tuple(values: np.ndarray) -> Pose:
    a = [float(v) for v in values]
    return (a[0], a[1], a[2], a[3], a[4], a[5])


def _as_pose(values: Sequence[float], what: str) -> Pose:
    if len(values) != 6 or not all(math.isfinite(float(v)) for v in values):
        raise ValueError(f"{what} must be 6 finite numbers (x, y, z mm, rx, ry, rz rad), got {values!r}")
    return _as_tuple(np.asarray(values, float))
