"""Air-float stiffness estimation (paper eqs. 1-8) as bus-independent logic the estimator node drives.

A sample is ``valid`` only when it is a stiffness reading of the specimen in a press: the SPS ring wholly on the
measured footprint (``ring_off_specimen`` otherwise: tips over the table tilt eqs. 1-3's plane; the outline comes
from the measured geometry, never the phantom), the indenter clear of its stroke's end (``at_stroke_end``: the
face lifted at a line's end or during a touch-off, the indenter on its stop; such readings came out at 100-480 kPa)
and the usual contact, depth, tilt and force checks. A subscriber needs no other topic to tell them apart.

Every height sample is matched by stamp — never by arrival order — with the probe force (pressure state,
interpolated) and the robot pose (interpolated); samples wait until both sides have data past their stamp, and
become invalid ("stale_*") when a side has none near it. Ramp mode additionally fits each pressure ramp's whole
force-depth curve with eqs. 6, 7 and 8.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from messages import PressureState, ProbeHeights, RobotPose, StiffnessFit, StiffnessSample
from models.airfloat import indentation_from_heights
from models.contact import corrected_modulus, fit_force_depth
from models.geometry import MeasuredGeometry
from models.timeseries import StampedBuffer

__all__ = ["AirfloatConfig", "AirfloatEstimator", "probe_thickness"]


@dataclass(frozen=True)
class AirfloatConfig:
    sps_radius_mm: float
    indenter_radius_mm: float
    thickness_mm: float
    poisson_ratio: float
    min_depth_mm: float
    max_depth_mm: float
    max_tilt_rad: float
    min_force_n: float
    stroke_mm: float
    max_wait_ns: int
    max_gap_ns: int
    ramp_fits: bool
    depth_offset_mm: float = 0.0
    """From the calibration: added to eqs. 1-3's d_in (SPS air gap, fibre zero)."""
    stroke_margin_mm: float = 1.0
    """An indenter extended within this of its stroke may rest on its stop (with bore friction and fibre noise it
    reads a little short of it): the force is then not the tissue's, and the sample is ``at_stroke_end``."""
    ring_tolerance_mm: float = 0.05
    """How far the SPS ring may reach past the measured footprint and still count as on the specimen."""
    thickness_from_probe: bool = False
    """Eq. 7's thickness at each sample from the probe itself (:func:`probe_thickness`) instead of the measured
    geometry or ``thickness_mm``."""


def probe_thickness(z_face_mm: np.ndarray, heights_mm: np.ndarray) -> np.ndarray:
    """The layer's thickness under the probe as the probe measures it: the height of the tissue surface under the
    face centre (the face's height less the mean of the three SPS extensions, which is the SPS plane's distance
    along the axis at the centre) above z = 0 of the phantom frame, the table as the frame is registered (touching
    the table beside the specimen: docs/robot.md; the estimator subtracts the height the scanner's table touch
    found, :attr:`AirfloatEstimator.table_z_mm`). Its error is the SPS's (noise, air gap) and the arm's
    height error, not a calliper's: BENCHMARKS.md "Finding all four"."""
    surface: np.ndarray = np.asarray(z_face_mm, dtype=float) - np.mean(np.asarray(heights_mm, dtype=float)[:, :3], axis=1)
    return surface


@dataclass
class AirfloatEstimator:
    """Feed it pose, pressure and heights; ``ready(now)`` returns the samples (and fits) that can be decided."""

    cfg: AirfloatConfig
    geometry: MeasuredGeometry | None = None
    """The measured thickness (map or constant); None: ``cfg.thickness_mm`` everywhere."""
    table_z_mm: float = 0.0
    """With ``thickness_from_probe``: the table's height in the phantom frame (0 as the frame is registered; the
    scanner's table touch, ``scanner/table``, measures it)."""
    pose: StampedBuffer = field(init=False)
    force: StampedBuffer = field(init=False)
    pending: list[ProbeHeights] = field(default_factory=list)
    faults_until_ns: int = 0
    ramp_f: list[float] = field(default_factory=list)
    ramp_d: list[float] = field(default_factory=list)
    ramp_t: list[float] = field(default_factory=list)
    ramp_xy: tuple[float, float] = (0.0, 0.0)
    in_ramp: bool = False
    fits: list[StiffnessFit] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.pose = StampedBuffer(max_gap_ns=self.cfg.max_gap_ns)
        self.force = StampedBuffer(max_gap_ns=self.cfg.max_gap_ns)

    def add_pose(self, m: RobotPose) -> None:
        self.pose.add(m.stamp_ns, (m.x_mm, m.y_mm, m.z_mm))

    def add_pressure(self, m: PressureState) -> None:
        self.force.add(m.stamp_ns, (m.force_n, 1.0 if m.faults else 0.0))
        if self.cfg.ramp_fits:
            if m.mode == "ramp":
                self.in_ramp = True
            elif self.in_ramp:
                self.in_ramp = False
                self._finish_ramp(m.stamp_ns)

    def add_heights(self, m: ProbeHeights) -> None:
        self.pending.append(m)

    def ready(self, now_ns: int) -> list[StiffnessSample]:
        """Decide every pending sample whose pose and force are known (or can no longer come)."""
        if not self.pending:
            return []
        horizon = min(self.pose.latest_stamp or 0, self.force.latest_stamp or 0)
        take = [m for m in self.pending if m.stamp_ns <= horizon or now_ns - m.stamp_ns > self.cfg.max_wait_ns]
        if not take:
            return []
        taken = {id(m) for m in take}
        self.pending = [m for m in self.pending if id(m) not in taken]
        return self._estimate(take)

    def _estimate(self, batch: list[ProbeHeights]) -> list[StiffnessSample]:
        c = self.cfg
        h = np.array([m.h_mm for m in batch], dtype=float)
        d_in, tilt = indentation_from_heights(h[:, 0], h[:, 1], h[:, 2], h[:, 3], c.sps_radius_mm,
                                              c.indenter_radius_mm)
        d_in, tilt = np.atleast_1d(d_in) + c.depth_offset_mm, np.atleast_1d(tilt)
        tol = c.max_gap_ns
        stamps = [m.stamp_ns for m in batch]
        poses = self.pose.at_each(stamps, tol)
        forces = self.force.at_each(stamps, tol)
        xyz = np.array([p if p is not None else (np.nan,) * 3 for p in poses])
        f = np.array([x[0] if x is not None else np.nan for x in forces])
        fault = np.array([x is not None and x[1] > 0 for x in forces])
        if c.thickness_from_probe:
            thick = probe_thickness(xyz[:, 2], h) - self.table_z_mm
        elif self.geometry is not None:
            thick = np.asarray(self.geometry.thickness(xyz[:, 0], xyz[:, 1]), dtype=float)
        else:
            thick = np.full(len(batch), c.thickness_mm)
        ok_geom = np.isfinite(thick) & (thick > 0)
        ring_on = self._ring_on_specimen(xyz[:, 0], xyz[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            e = np.asarray(corrected_modulus(f, d_in, c.indenter_radius_mm, np.where(ok_geom, thick, 1.0),
                                             c.poisson_ratio), dtype=float)
        out = []
        # Python floats and bools of the same values, each array in one call: per-element numpy indexing and
        # comparisons cost ~0.1-1 us each, a dozen per sample (issue 40)
        xyz_rows = xyz.tolist()
        d_l, tilt_l, f_l, e_l, thick_l = d_in.tolist(), tilt.tolist(), f.tolist(), e.tolist(), thick.tolist()
        fault_l, ring_l, geom_l = fault.tolist(), np.asarray(ring_on).tolist(), ok_geom.tolist()
        for i, m in enumerate(batch):
            reason = ""
            fi, di = f_l[i], d_l[i]
            if poses[i] is None:
                reason = "stale_pose"
            elif forces[i] is None:
                reason = "stale_pressure"
            elif fault_l[i]:
                reason = "pressure_fault"
            elif max(m.h_mm) >= c.stroke_mm - 1e-6 or fi <= c.min_force_n:
                reason = "no_contact"
            elif not ring_l[i]:
                reason = "ring_off_specimen"
            elif m.h_mm[3] > c.stroke_mm - c.stroke_margin_mm:
                reason = "at_stroke_end"
            elif not geom_l[i]:
                reason = "off_geometry"
            elif tilt_l[i] > c.max_tilt_rad:
                reason = "tilt_too_large"
            elif di < c.min_depth_mm:
                reason = "too_shallow"
            elif di > c.max_depth_mm:
                reason = "too_deep"
            elif not math.isfinite(e_l[i]):
                reason = "no_solution"
            valid = not reason
            x, y, z = (v if math.isfinite(v) else 0.0 for v in xyz_rows[i])
            out.append(StiffnessSample(
                stamp_ns=m.stamp_ns, model="airfloat", x_mm=x, y_mm=y, z_mm=z,
                value=e_l[i] if valid else float("nan"), unit="kPa", valid=valid, reason=reason,
                d_in_mm=di, force_n=fi if math.isfinite(fi) else 0.0,
                tilt_rad=tilt_l[i], thickness_mm=thick_l[i] if geom_l[i] else 0.0,
            ))
            if valid and self.in_ramp:
                self.ramp_f.append(fi)
                self.ramp_d.append(di)
                self.ramp_t.append(thick_l[i])
                self.ramp_xy = (x, y)
        return out

    def _ring_on_specimen(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Per pose, whether the SPS ring (radius ``sps_radius_mm`` about the face centre) lies on the measured
        footprint; all True when the geometry gives none (a constant thickness says nothing of where it ends)."""
        fp = self.geometry.footprint_mm() if self.geometry is not None else None
        if fp is None:
            return np.ones(x.shape, dtype=bool)
        x0, y0, x1, y1 = fp
        r = self.cfg.sps_radius_mm - self.cfg.ring_tolerance_mm
        with np.errstate(invalid="ignore"):
            on: np.ndarray = (x - r >= x0) & (x + r <= x1) & (y - r >= y0) & (y + r <= y1)
        return on

    def _finish_ramp(self, stamp_ns: int) -> None:
        f, d, t = self.ramp_f, self.ramp_d, self.ramp_t
        self.ramp_f, self.ramp_d, self.ramp_t = [], [], []
        if len(f) < 5:
            return
        thick = self.cfg.thickness_mm
        if self.cfg.thickness_from_probe:
            thick = float(np.median(t))
        elif self.geometry is not None:
            thick = float(self.geometry.thickness(*self.ramp_xy))
        fit = fit_force_depth(np.array(f), np.array(d), self.cfg.indenter_radius_mm, thick, self.cfg.poisson_ratio)
        self.fits.append(StiffnessFit(
            stamp_ns=stamp_ns, x_mm=self.ramp_xy[0], y_mm=self.ramp_xy[1], e_hertz_kpa=float(fit.E_hertz),
            e_corrected_kpa=float(fit.E_corrected), e_fung_kpa=float(fit.E_fung), b_fung=float(fit.b_fung),
            points=len(f), rms_residual_n=float(fit.residuals.corrected), max_depth_mm=float(max(d)),
        ))
