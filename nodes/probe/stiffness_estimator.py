"""Stiffness estimator nodes: probe measurements -> ``stiffness/sample`` (and ``stiffness/fit`` for ramps).

Two node classes, one per probe, each with only its own parameters:

- :class:`AirfloatStiffnessEstimator` — the air-float probe (eqs. 1-8): heights (``probe/heights``) + force
  (``pressure/state``) + pose (``robot/pose``), matched by stamp.
- :class:`MultiIndenterStiffnessEstimator` — the camera probe (eq. 5): indenter displacements
  (``camera/indenters``) + pose.
"""

from __future__ import annotations

import math
from array import array
from typing import Literal

import palpa
from messages import (
    IndenterDisplacements,
    PressureState,
    ProbeHeights,
    RobotPose,
    StiffnessFit,
    StiffnessSample,
    TableHeight,
)
from models.airfloat import DEFAULT_INDENTER_RADIUS_MM, DEFAULT_SPS_RADIUS_MM
from models.calibration_airfloat import CalibrationError, load_calibration
from models.geometry import GeometryError, load_geometry
from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry
from nodes.common import load_probe_calibration
from nodes.probe.estimator_airfloat import AirfloatConfig, AirfloatEstimator
from nodes.probe.estimator_multi import MultiIndenterEstimator

__all__ = ["AirfloatStiffnessEstimator", "MultiIndenterStiffnessEstimator"]


class _MatchingParams(palpa.Params):
    """What both estimators share: how samples wait for the pose (and force) they are matched with."""

    rate_hz: palpa.Positive = 50.0
    """How often pending samples are decided and published."""
    max_wait_s: palpa.Positive = 0.25
    """A sample whose pose/force has not arrived by then is published invalid (stale)."""
    max_gap_s: palpa.Positive = 0.1
    """Largest hole in pose/force history that is still interpolated across."""


class _Publishing(palpa.Node):
    """The outputs both estimators publish."""

    def open_outputs(self) -> None:
        self.samples = self.publisher("stiffness/sample", StiffnessSample)
        self.fits = self.publisher("stiffness/fit", StiffnessFit)
        self.published = 0
        # value, pan and tilt of each valid sample, for the result line: flat arrays of doubles (8 bytes a number; a
        # tuple a sample was ~100 bytes, 30 MB over a 10-minute scan at 500 Hz)
        self.values, self.pans, self.tilts = array("d"), array("d"), array("d")
        self.unit = ""

    def publish_samples(self, out: list[StiffnessSample]) -> None:
        for s in out:
            self.samples.publish(s)
            self.published += 1
            if s.valid and math.isfinite(s.value):
                self.values.append(s.value)
                self.pans.append(s.pan_rad)
                self.tilts.append(s.tilt_rad)
                self.unit = s.unit

    def result_line(self) -> str:
        """The run's result in one line (logged at shutdown, shown after the progress bar by a launch file's
        ``progress: {report: [estimator]}``): the median estimate over the valid samples, with their spread."""
        if not self.values:
            return f"result: no valid stiffness estimate in {self.published} samples"
        values = sorted(self.values)
        n = len(values)
        pans, tilts = sorted(self.pans), sorted(self.tilts)
        return (f"result: stiffness median {values[n // 2]:.4g} {self.unit} over {n} valid of {self.published} "
                f"samples (10-90 %: {values[n // 10]:.4g} to {values[(9 * n) // 10]:.4g}); pan median "
                f"{math.degrees(pans[n // 2]):.1f} deg, tilt median {math.degrees(tilts[n // 2]):.1f} deg")

    def on_shutdown(self) -> None:
        """Say the result (what the run was for) before the node goes."""
        self.log.info("%s", self.result_line())


class AirfloatStiffnessEstimator(_Publishing):
    """The air-float probe's estimator: a thin adapter between the bus and :class:`AirfloatEstimator`."""

    class Params(_MatchingParams):
        thickness_mm: palpa.Positive = 20.0
        """Tissue thickness for eq. 7 (mm) when no ``geometry`` file is given: a value someone measured."""
        calibration: palpa.InputPath = ""
        """Calibration YAML (``python -m tools.calibrate_airfloat``): its depth offset is added to eqs. 1-3's d_in."""
        geometry: palpa.InputPath = ""
        """Measured-geometry YAML (a thickness map or constant, docs/physics.md); overrides ``thickness_mm``."""
        thickness: Literal["probe", "geometry"] = "geometry"
        """Where eq. 7's thickness comes from: ``geometry`` (the file above, else ``thickness_mm``) or ``probe``
        (the surface under the probe above the table, measured at every sample: estimator_airfloat.probe_thickness;
        no file needed; the table is z = 0 of the frame until the scanner's table touch says where it is on
        ``scanner/table``)."""
        poisson_ratio: float = 0.5
        sps_radius_mm: palpa.Positive = DEFAULT_SPS_RADIUS_MM
        indenter_radius_mm: palpa.Positive = DEFAULT_INDENTER_RADIUS_MM
        min_depth_mm: palpa.NonNegative = 0.3
        max_depth_mm: palpa.Positive = 5.0
        max_tilt_deg: palpa.Positive = 30.0
        min_force_n: palpa.NonNegative = 0.02
        stroke_mm: palpa.Positive = 10.0
        stroke_margin_mm: palpa.NonNegative = 1.0
        """An indenter extended within this of its stroke may rest on its stop: its samples are invalid
        (``at_stroke_end``)."""
        ramp_fits: bool = False
        """Fit each pressure ramp's force-depth curve with eqs. 6-8 (``stiffness/fit``)."""

    params: Params

    def setup(self) -> None:
        p = self.params
        try:
            geometry = load_geometry(p.geometry) if p.geometry else None
            offset = load_calibration(p.calibration).depth_offset_mm if p.calibration else 0.0
        except (GeometryError, CalibrationError) as exc:
            raise palpa.ParamError(f"{self.name}: {exc}") from None
        self.air = AirfloatEstimator(AirfloatConfig(
            sps_radius_mm=p.sps_radius_mm, indenter_radius_mm=p.indenter_radius_mm,
            thickness_mm=p.thickness_mm, poisson_ratio=p.poisson_ratio, min_depth_mm=p.min_depth_mm,
            max_depth_mm=p.max_depth_mm, max_tilt_rad=math.radians(p.max_tilt_deg),
            min_force_n=p.min_force_n, stroke_mm=p.stroke_mm, max_wait_ns=int(p.max_wait_s * 1e9),
            max_gap_ns=int(p.max_gap_s * 1e9), ramp_fits=p.ramp_fits, depth_offset_mm=offset,
            stroke_margin_mm=p.stroke_margin_mm,
            thickness_from_probe=p.thickness == "probe",
        ), geometry)
        self.open_outputs()
        self.subscribe("robot/pose", self.on_pose)
        self.subscribe("probe/heights", self.on_heights)
        self.subscribe("pressure/state", self.on_pressure)
        if p.thickness == "probe":
            self.subscribe("scanner/table", self.on_table)
        self.timer(1.0 / p.rate_hz, self.flush_ready)

    def on_table(self, m: TableHeight) -> None:
        """The scanner touched the table: the probe's thickness counts from its height from now on."""
        self.air.table_z_mm = m.z_mm
        self.log.info("thickness from the probe above the table at z %.2f mm (touched at (%g, %g) mm)",
                      m.z_mm, m.x_mm, m.y_mm)

    def on_pose(self, m: RobotPose) -> None:
        self.air.add_pose(m)

    def on_pressure(self, m: PressureState) -> None:
        self.air.add_pressure(m)

    def on_heights(self, m: ProbeHeights) -> None:
        self.air.add_heights(m)

    def flush_ready(self) -> None:
        self.publish_samples(self.air.ready(self.clock.now_ns()))
        fits, self.air.fits = self.air.fits, []
        for f in fits:
            self.log.info("ramp fit at (%.1f, %.1f): E eq.6 %.1f kPa, eq.7 %.1f kPa, eq.8 %.1f kPa (b %.2f, %d points)",
                          f.x_mm, f.y_mm, f.e_hertz_kpa, f.e_corrected_kpa, f.e_fung_kpa, f.b_fung, f.points)
            self.fits.publish(f)


class MultiIndenterStiffnessEstimator(_Publishing):
    """The camera probe's estimator: a thin adapter between the bus and :class:`MultiIndenterEstimator`."""

    class Params(_MatchingParams):
        solver: Literal["exact", "lm"] = "exact"
        soft_spring_n_per_mm: palpa.Positive = 0.05
        hard_spring_n_per_mm: palpa.Positive = 0.25
        indenter_circle_radius_mm: palpa.NonNegative = 0.0
        """0: the model's default geometry."""
        min_displacement_mm: palpa.NonNegative = 0.05
        max_condition: palpa.Positive = 1e6
        calibration_file: palpa.InputPath = ""
        """A probe calibration file whose spring constants replace the nominal ones."""

    params: Params

    def setup(self) -> None:
        p = self.params
        self.multi = MultiIndenterEstimator(self.probe_geometry(), p.solver, p.min_displacement_mm, p.max_condition,
                                            int(p.max_wait_s * 1e9), int(p.max_gap_s * 1e9))
        self.open_outputs()
        self.subscribe("robot/pose", self.on_pose)
        self.subscribe("camera/indenters", self.on_indenters)
        self.timer(1.0 / p.rate_hz, self.flush_ready)

    def probe_geometry(self) -> ProbeGeometry:
        """The paper's probe with these spring constants (and circle radius, if given); ``calibration_file``
        replaces the spring constants by the probe's own, identified on reference springs."""
        p = self.params
        kwargs: dict[str, float] = {"k_soft_n_per_mm": p.soft_spring_n_per_mm,
                                    "k_hard_n_per_mm": p.hard_spring_n_per_mm}
        if p.indenter_circle_radius_mm > 0:
            kwargs["radius_mm"] = p.indenter_circle_radius_mm
        geometry = ProbeGeometry.paper(**kwargs) if kwargs != {"k_soft_n_per_mm": 0.05, "k_hard_n_per_mm": 0.25} \
            else PAPER_GEOMETRY
        if p.calibration_file:
            k = load_probe_calibration(p.calibration_file, self.name).k_n_per_mm
            geometry = ProbeGeometry(geometry.x_mm, geometry.y_mm, k, geometry.stroke_mm)
        return geometry

    def on_pose(self, m: RobotPose) -> None:
        self.multi.add_pose(m)

    def on_indenters(self, m: IndenterDisplacements) -> None:
        self.multi.add_indenters(m)

    def flush_ready(self) -> None:
        self.publish_samples(self.multi.ready(self.clock.now_ns()))

