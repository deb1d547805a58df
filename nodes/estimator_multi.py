"""Multi-indenter (camera probe) stiffness estimation, eq. 5 of the camera-probe paper, as bus-independent
logic the estimator node drives: indenter displacements + the robot pose matched by stamp -> K_t, pan, tilt."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from messages import IndenterDisplacements, RobotPose, StiffnessSample
from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry, solve_exact, solve_lm
from models.timeseries import StampedBuffer
from nodes.common import load_probe_calibration

__all__ = ["MultiIndenterEstimator"]


@dataclass
class MultiIndenterEstimator:
    """Feed it poses and indenter frames; ``ready(now)`` returns the decided samples."""

    geometry: ProbeGeometry
    solver: str = "exact"
    contact_threshold_mm: float = 0.05
    max_condition: float = 1e4
    max_wait_ns: int = 250_000_000
    max_gap_ns: int = 100_000_000
    pose: StampedBuffer = field(init=False)
    pending: list[IndenterDisplacements] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.pose = StampedBuffer(max_gap_ns=self.max_gap_ns)

    @classmethod
    def from_params(cls, p: Any) -> MultiIndenterEstimator:
        """Build from the estimator node's parameters (spring constants and geometry have the paper's defaults;
        ``calibration_file`` replaces the spring constants by the probe's identified ones)."""
        kwargs: dict[str, float] = {"k_soft_n_per_mm": p.soft_spring_n_per_mm,
                                    "k_hard_n_per_mm": p.hard_spring_n_per_mm}
        if p.indenter_circle_radius_mm > 0:
            kwargs["radius_mm"] = p.indenter_circle_radius_mm
        geometry = ProbeGeometry.paper(**kwargs) if kwargs != {"k_soft_n_per_mm": 0.05, "k_hard_n_per_mm": 0.25} \
            else PAPER_GEOMETRY
        if p.calibration_file:
            # the probe's own springs, identified on reference springs (nodes/camera_calibrate.py)
            k = load_probe_calibration(p.calibration_file, "estimator").k_n_per_mm
            geometry = ProbeGeometry(geometry.x_mm, geometry.y_mm, k, geometry.stroke_mm)
        return cls(geometry, p.solver, p.min_displacement_mm, p.max_condition, int(p.max_wait_s * 1e9),
                   int(p.max_gap_s * 1e9))

    def add_pose(self, m: RobotPose) -> None:
        self.pose.add(m.stamp_ns, (m.x_mm, m.y_mm, m.z_mm))

    def add_indenters(self, m: IndenterDisplacements) -> None:
        self.pending.append(m)

    def ready(self, now_ns: int) -> list[StiffnessSample]:
        horizon = self.pose.latest_stamp or 0
        out, keep = [], []
        for m in self.pending:
            if m.stamp_ns <= horizon or now_ns - m.stamp_ns > self.max_wait_ns:
                out.append(self._estimate(m))
            else:
                keep.append(m)
        self.pending = keep
        return out

    def _estimate(self, m: IndenterDisplacements) -> StiffnessSample:
        pose = self.pose.at(m.stamp_ns, self.max_gap_ns)
        # a lost marker is NaN, so the solver reports it instead of solving on a Kalman prediction
        dx = [d if ok else math.nan for d, ok in zip(m.displacement_mm, m.valid, strict=True)]
        solve = solve_lm if self.solver == "lm" else solve_exact
        sol = solve(dx, self.geometry, contact_threshold_mm=self.contact_threshold_mm,
                    max_condition=self.max_condition)
        reason = "" if sol.valid else sol.reason
        if pose is None:
            reason = "stale_pose"
        valid = not reason
        x, y, z = pose if pose is not None else (0.0, 0.0, 0.0)
        return StiffnessSample(
            stamp_ns=m.stamp_ns, model="multi_indenter", x_mm=x, y_mm=y, z_mm=z,
            value=float(sol.k_t_n_per_mm) if valid else math.nan, unit="N/mm", valid=valid, reason=reason,
            tilt_rad=float(sol.tilt_rad) if sol.valid else 0.0, pan_rad=float(sol.pan_rad) if sol.valid else 0.0,
            dt_mm=[float(v) for v in sol.dt_mm] if sol.valid else [],
        )
