"""Paths of the arm model: moveL waypoints, their blended geometry and time-optimal trapezoidal speed profile.

Split out of ``models.arm`` (which runs the plans on the controller's 2 ms clock); pure functions and value
classes, no state between calls. Orientations are rotation vectors; quaternions are (w, x, y, z).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Pose = tuple[float, float, float, float, float, float]

MM_PER_RAD = 1000.0  # path length that one radian of pure tool rotation counts as
EPS_MM = 1e-9
_MIN_BLEND_MM = 1e-6  # blends below this are treated as none
_MIN_BLEND_SPEED_FRACTION = 0.2  # blends slower than this fraction of the path speed become stops
_BEZIER_SAMPLES = 65


def quat(rotvec: np.ndarray | Sequence[float]) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation vector."""
    v = np.asarray(rotvec, float)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.array([1.0, 0.5 * v[0], 0.5 * v[1], 0.5 * v[2]])
    return np.concatenate(([math.cos(angle / 2)], v * (math.sin(angle / 2) / angle)))


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion of rotation a applied after rotation b."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (angle <= pi) of a quaternion."""
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-12:
        return np.asarray(2.0 * q[1:], float)
    return np.asarray(q[1:] * (2.0 * math.atan2(s, q[0]) / s), float)


def turn(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Rotation vector taking orientation q0 to q1 (in the base frame)."""
    return quat_to_rotvec(qmul(q1, q0 * np.array([1.0, -1.0, -1.0, -1.0])))


@dataclass(frozen=True)
class ArmTarget:
    """One moveL waypoint: pose (mm, rad), tool speed (mm/s), acceleration (mm/s^2), and the
    blend radius (mm) around this waypoint (ignored on the last waypoint of a path)."""

    pose: Pose
    speed_mm_s: float
    accel_mm_s2: float
    blend_mm: float = 0.0


def check_target(i: int, t: ArmTarget) -> None:
    """Refuse waypoint i with a ValueError naming it unless its pose, speed, acceleration and blend are usable."""
    if len(t.pose) != 6 or not all(math.isfinite(v) for v in t.pose):
        raise ValueError(f"waypoint {i}: pose must be 6 finite numbers (x, y, z mm, rx, ry, rz rad), got {t.pose!r}")
    for name, value, lo in (("speed_mm_s", t.speed_mm_s, 0.0), ("accel_mm_s2", t.accel_mm_s2, 0.0)):
        if not (math.isfinite(value) and value > lo):
            raise ValueError(f"waypoint {i}: {name} must be a finite number > 0, got {value!r}")
    if not (math.isfinite(t.blend_mm) and t.blend_mm >= 0.0):
        raise ValueError(f"waypoint {i}: blend_mm must be a finite number >= 0, got {t.blend_mm!r}")


class Primitive:
    """A piece of path parametrised by length u in [0, length]: a line, a pure rotation, or a
    quadratic Bezier blend. Orientation is slerped linearly in u from rot0 to rot1."""

    def __init__(self, p0: np.ndarray, p1: np.ndarray, rot0: np.ndarray, rot1: np.ndarray,
                 vmax: float, accel: float, index: int, ctrl: np.ndarray | None = None,
                 rotvec0: np.ndarray | None = None) -> None:
        self.p0, self.p1, self.ctrl, self.rot0 = p0, p1, ctrl, rot0
        self.rotvec0 = quat_to_rotvec(rot0) if rotvec0 is None else rotvec0
        self.dw = turn(rot0, rot1)  # rotation to apply over the whole primitive
        self.accel, self.index = accel, index
        self._turns = bool(np.any(self.dw))
        self._line_twist: tuple[np.ndarray, np.ndarray] | None = None
        self._line_twist6: np.ndarray | None = None
        self._lists: tuple[list[float], list[float], list[float], list[float], list[float]] | None = None
        angle_mm = float(np.linalg.norm(self.dw)) * MM_PER_RAD
        self._delta = p1 - p0
        if ctrl is None:
            self.lin = float(np.linalg.norm(p1 - p0))
            self.length = self.lin if self.lin > EPS_MM else angle_mm
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
            if self.lin <= EPS_MM:
                return self.p0
            return np.asarray(self.p0 + self._delta * (u / self.length), float)
        t = self._tau_of(u)
        return np.asarray((1 - t) ** 2 * self.p0 + 2 * (1 - t) * t * self.ctrl + t**2 * self.p1, float)

    def pose_at(self, u: float) -> Pose:
        """:meth:`position` and :meth:`rotvec` at u as one pose of Python floats: the same arithmetic, element by
        element, without a numpy call per 3-vector (the arm model asks at every 2 ms tick of a simulation)."""
        lists = self._lists
        if lists is None:
            bend = self.p0 if self.ctrl is None else self.ctrl
            lists = self._lists = (self.p0.tolist(), self._delta.tolist(), bend.tolist(), self.p1.tolist(),
                                   np.asarray(self.rotvec0, float).tolist())
        p0, delta, ctrl, p1, rv0 = lists
        pos: list[float]
        if self.ctrl is None:
            if self.lin <= EPS_MM:
                pos = p0
            else:
                k = float(u) / self.length
                pos = [a + d * k for a, d in zip(p0, delta, strict=True)]
        else:
            t = self._tau_of(u)
            a, b, c = (1 - t) ** 2, 2 * (1 - t) * t, t**2  # position()'s scalars, in its order
            pos = [a * x + b * y + c * z for x, y, z in zip(p0, ctrl, p1, strict=True)]
        rv = self.rotvec(u).tolist() if self._turns else rv0
        return (pos[0], pos[1], pos[2], rv[0], rv[1], rv[2])

    def rotvec(self, u: float) -> np.ndarray:
        if not self._turns:
            return self.rotvec0
        return quat_to_rotvec(qmul(quat(self.dw * (u / self.length)), self.rot0))

    def twist6_per_mm(self, u: float) -> np.ndarray:
        """:meth:`twist_per_mm` as one 6-vector (linear, then angular; an array the caller must not change)."""
        if self.ctrl is None:
            if self._line_twist6 is None:
                self._line_twist6 = np.concatenate(self.twist_per_mm(u))
            return self._line_twist6
        return np.concatenate(self.twist_per_mm(u))

    def twist_per_mm(self, u: float) -> tuple[np.ndarray, np.ndarray]:
        """(linear direction, angular rate) per mm of path at u (arrays the caller must not change: a line's are
        the same at every u, and made once)."""
        if self.ctrl is None:
            if self._line_twist is None:
                lin = (self.p1 - self.p0) / self.length if self.lin > EPS_MM else np.zeros(3)
                self._line_twist = (lin, self.dw / self.length)
            return self._line_twist
        ang = self.dw / self.length
        t = self._tau_of(u)
        d = 2 * (1 - t) * (self.ctrl - self.p0) + 2 * t * (self.p1 - self.ctrl)
        return d / max(float(np.linalg.norm(d)), 1e-300), ang


@dataclass(frozen=True)
class Trapezoid:
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


class PathPlan:
    """Geometry and time-optimal speed profile of one moveL path started from rest."""

    def __init__(self, start: Pose, targets: Sequence[ArmTarget]) -> None:
        self.final_pose = targets[-1].pose
        self.count = len(targets)
        pts = [np.asarray(start[:3], float)] + [np.asarray(t.pose[:3], float) for t in targets]
        rvs = [np.asarray(start[3:], float)] + [np.asarray(t.pose[3:], float) for t in targets]
        rots = [quat(r) for r in rvs]
        seg_len = [float(np.linalg.norm(pts[i + 1] - pts[i])) for i in range(len(targets))]
        # effective blend radius at waypoint i (between segment i and i+1); blends never overlap
        blend = [0.0] * len(targets)
        for i in range(len(targets) - 1):
            if seg_len[i] <= EPS_MM or seg_len[i + 1] <= EPS_MM:
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
        prims: list[Primitive] = []
        smooth: list[bool] = []  # smooth[k]: junction before primitive k is tangent-continuous

        def at(i: int, frac: float) -> tuple[np.ndarray, np.ndarray]:
            """Position and orientation at fraction frac of segment i (waypoint i-1 -> i)."""
            return pts[i] + (pts[i + 1] - pts[i]) * frac, qmul(quat(turn(rots[i], rots[i + 1]) * frac), rots[i])

        for i, tgt in enumerate(targets):
            v, a = tgt.speed_mm_s, tgt.accel_mm_s2
            f0 = blend[i - 1] / seg_len[i] if i > 0 and blend[i - 1] > 0 else 0.0
            f1 = 1.0 - blend[i] / seg_len[i] if blend[i] > 0 else 1.0
            p_a, r_a = at(i, f0)
            p_b, r_b = at(i, f1)
            rv0 = rvs[i] if f0 == 0.0 else None
            line = Primitive(p_a, p_b, r_a, r_b, v, a, i, rotvec0=rv0)
            if line.length > EPS_MM:
                prev_dir = prims[-1].twist_per_mm(prims[-1].length)[0] if prims else None
                this_dir = line.twist_per_mm(0.0)[0]
                smooth.append(prev_dir is not None and line.lin > EPS_MM
                              and float(np.dot(prev_dir, this_dir)) > 1.0 - 1e-9)
                prims.append(line)
            if blend[i] > 0:
                nxt = targets[i + 1]
                q0, q1 = at(i + 1, blend[i] / seg_len[i + 1])
                curve = Primitive(p_b, q0, r_b, q1, min(v, nxt.speed_mm_s),
                                   min(a, nxt.accel_mm_s2), i + 1, ctrl=pts[i + 1])
                if curve.length > EPS_MM:
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
        self.traps: list[Trapezoid] = []
        self.t_starts = [0.0]
        for k, p in enumerate(prims):
            peak = math.sqrt((2 * p.accel * p.length + w[k] ** 2 + w[k + 1] ** 2) / 2)
            trap = Trapezoid(p.length, w[k], w[k + 1], max(min(p.vmax, peak), w[k], w[k + 1]), p.accel)
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

    def locate(self, s: float) -> tuple[Primitive, float]:
        k = min(max(bisect.bisect_right(self.starts, s) - 1, 0), len(self.prims) - 1)
        return self.prims[k], min(max(s - self.starts[k], 0.0), self.prims[k].length)

    def speed_limit_ahead(self, s: float) -> list[tuple[float, float]]:
        """(distance ahead, speed limit) at every junction and primitive start after s."""
        return [(self.starts[k] - s, self.prims[k].vmax) for k in range(len(self.prims)) if self.starts[k] > s]
