"""Multi-indenter (camera probe) stiffness estimation, eq. 5 of the camera-probe paper, as bus-independent
logic the estimator node drives: indenter displacements + the robot pose matched by stamp -> K_t, pan, tilt."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from messages import IndenterDisplacements, RobotPose, StiffnessSample
from models.multi_indenter import ProbeGeometry
from models.multi_indenter_solve import solve_exact, solve_lm
from models.timeseries import StampedBuffer

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
