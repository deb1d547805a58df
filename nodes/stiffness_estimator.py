"""Stiffness estimator node: probe measurements -> ``stiffness/sample`` (and ``stiffness/fit`` for ramps).

``model: airfloat`` — the air-float probe (eqs. 1-8): heights (``probe/heights``) + force (``pressure/state``) +
pose (``robot/pose``), matched by stamp. ``model: multi_indenter`` — the camera probe (eq. 5): indenter
displacements (``camera/indenters``) + pose.
"""

from __future__ import annotations

import math
from typing import Literal

import palpa
from messages import (
    IndenterDisplacements,
    PressureState,
    ProbeHeights,
    RobotPose,
    StiffnessFit,
    StiffnessSample,
)
from models.airfloat import DEFAULT_INDENTER_RADIUS_MM, DEFAULT_SPS_RADIUS_MM
from models.geometry import GeometryError, load_geometry
from nodes.estimator_airfloat import AirfloatConfig, AirfloatEstimator

__all__ = ["StiffnessEstimator"]


class StiffnessEstimator(palpa.Node):
    """Thin adapter between the bus and the estimation models."""

    class Params(palpa.Params):
        model: Literal["airfloat", "multi_indenter"] = "airfloat"
        rate_hz: float = 50.0
        """How often pending samples are decided and published."""
        max_wait_s: float = 0.25
        """A sample whose pose/force has not arrived by then is published invalid (stale)."""
        max_gap_s: float = 0.1
        """Largest hole in pose/force history that is still interpolated across."""
        # air-float
        thickness_mm: float = 20.0
        """Tissue thickness for eq. 7 (mm) when no ``geometry`` file is given: a value someone measured."""
        geometry: str = ""
        """Measured-geometry YAML (a thickness map or constant, docs/physics.md); overrides ``thickness_mm``."""
        poisson_ratio: float = 0.5
        sps_radius_mm: float = DEFAULT_SPS_RADIUS_MM
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM
        min_depth_mm: float = 0.3
        max_depth_mm: float = 5.0
        max_tilt_deg: float = 30.0
        min_force_n: float = 0.02
        stroke_mm: float = 10.0
        ramp_fits: bool = False
        """Fit each pressure ramp's force-depth curve with eqs. 6-8 (``stiffness/fit``)."""
        # multi-indenter
        solver: Literal["exact", "lm"] = "exact"
        soft_spring_n_per_mm: float = 0.05
        hard_spring_n_per_mm: float = 0.25
        indenter_circle_radius_mm: float = 0.0
        """0: the model's default geometry."""
        min_displacement_mm: float = 0.05
        max_condition: float = 1e6

    def setup(self) -> None:
        p = self.params
        self.samples = self.publisher("stiffness/sample", StiffnessSample)
        self.fits = self.publisher("stiffness/fit", StiffnessFit)
        self.published = 0
        self.subscribe("robot/pose", self.on_pose)
        if p.model == "airfloat":
            try:
                geometry = load_geometry(p.geometry) if p.geometry else None
            except GeometryError as exc:
                raise palpa.ParamError(f"{self.name}: geometry: {exc}") from None
            self.air = AirfloatEstimator(AirfloatConfig(
                sps_radius_mm=p.sps_radius_mm, indenter_radius_mm=p.indenter_radius_mm,
                thickness_mm=p.thickness_mm, poisson_ratio=p.poisson_ratio, min_depth_mm=p.min_depth_mm,
                max_depth_mm=p.max_depth_mm, max_tilt_rad=math.radians(p.max_tilt_deg),
                min_force_n=p.min_force_n, stroke_mm=p.stroke_mm, max_wait_ns=int(p.max_wait_s * 1e9),
                max_gap_ns=int(p.max_gap_s * 1e9), ramp_fits=p.ramp_fits,
            ), geometry)
            self.subscribe("probe/heights", self.on_heights)
            self.subscribe("pressure/state", self.on_pressure)
        else:
            from nodes.estimator_multi import MultiIndenterEstimator

            self.multi = MultiIndenterEstimator.from_params(p)
            self.subscribe("camera/indenters", self.on_indenters)
        self.timer(1.0 / p.rate_hz, self.flush_ready)

    def on_pose(self, m: RobotPose) -> None:
        if self.params.model == "airfloat":
            self.air.add_pose(m)
        else:
            self.multi.add_pose(m)

    def on_pressure(self, m: PressureState) -> None:
        self.air.add_pressure(m)

    def on_heights(self, m: ProbeHeights) -> None:
        self.air.add_heights(m)

    def on_indenters(self, m: IndenterDisplacements) -> None:
        self.multi.add_indenters(m)

    def flush_ready(self) -> None:
        now = self.clock.now_ns()
        if self.params.model == "airfloat":
            out = self.air.ready(now)
            fits, self.air.fits = self.air.fits, []
        else:
            out = self.multi.ready(now)
            fits = []
        for s in out:
            self.samples.publish(s)
            self.published += 1
        for f in fits:
            self.log.info("ramp fit at (%.1f, %.1f): E eq.6 %.1f kPa, eq.7 %.1f kPa, eq.8 %.1f kPa (b %.2f, %d points)",
                          f.x_mm, f.y_mm, f.e_hertz_kpa, f.e_corrected_kpa, f.e_fung_kpa, f.b_fung, f.points)
            self.fits.publish(f)


if __name__ == "__main__":
    palpa.run_node(StiffnessEstimator)
