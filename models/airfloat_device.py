"""The simulated air-float probe as a device: its TRUE force law and its sensors' errors (world side).

This is the probe the simulated drivers embody, not the estimator's model of it. The estimator knows eq. 4 as a
calibration (``models.airfloat.ForceCalibration``) and eqs. 1-3; this module shares neither object nor formula
with them. Every error is drawn once per device from a seed (:meth:`ProbeErrors.draw`) and can be written into the
run (``as_dict``); :meth:`ProbeErrors.ideal` is a perfect device for unit tests only. Magnitudes and their
sources (docs/physics.md, "The simulated air-float device"):

* **Force law.** The paper's Fig. 10 line F = 7.59 P[bar] - 2.34 is this probe's fit; the device's true line
  differs by a drawn gain (sigma 0.5 %: 0.013 N at 33 kPa) and offset (sigma 0.01 N), bends by a drawn quadratic (the Fig. 6 CFD curves
  are linear only to ~0.2 N RMSE) and has **hysteresis**: the indenter rubs in its bore, so the tissue feels
  F_air - f when the indenter extends and F_air + f when it is pushed in (Fig. 9's advance/retrieve loops).
  f ~ 0.03 N and the bend make eq. 4's straight-line fit residual ~0.04 N RMSE, as the paper reports.
* **Probe pressure.** The probe's internal pressure differs from the regulator's read-back by a line/sensor
  offset (sigma 0.2 kPa); the regulator's tracking wobble (+-0.5 kPa) is in ``models.regulator``'s sim driver.
* **Fibre sensors** (Fig. 3): each channel's calibration leaves a gain error (sigma 1 %) and a bow (sigma
  0.02 mm at mid-stroke) - the calibration polynomial's residual.
* **SPS air gap.** Each surface profile sensor floats on its air cushion (Fig. 2) a gap g = g0 sqrt(P / 36 kPa)
  above the tissue, g0 ~ 0.04 mm +- 25 % per sensor: the SPS plane sits closer to the probe face than the tissue.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from models._arrays import ArrayLike, FloatArray
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out

__all__ = ["ProbeErrors", "TrueProbe"]

# One real probe's measured law (paper Fig. 10, eq. 4), P in bar: the centre of the device draws.
_PAPER_GAIN_N_PER_BAR = 7.59
_PAPER_OFFSET_N = -2.34
_BAR_KPA = 100.0
_GAP_REF_KPA = 36.0


@dataclass(frozen=True)
class ProbeErrors:
    """One simulated probe's error draw (all the world's secrets about the device)."""

    force_gain_n_per_bar: float = _PAPER_GAIN_N_PER_BAR
    force_offset_n: float = _PAPER_OFFSET_N
    force_bend_n_per_kpa2: float = 0.0
    """Quadratic term about 38 kPa (mid operating range)."""
    friction_n: float = 0.0
    pressure_offset_kpa: float = 0.0
    """Probe pressure minus regulator read-back."""
    fibre_gain: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    fibre_bow_mm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    sps_gap_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Air-cushion gap of SPS1..3 at 36 kPa."""
    noise_mm: float = 0.0
    seed: int | None = None

    @classmethod
    def ideal(cls) -> ProbeErrors:
        """A perfect device: the paper's line exactly, no hysteresis, exact sensors (unit tests only)."""
        return cls()

    @classmethod
    def draw(cls, seed: int, *, noise_mm: float = 0.005) -> ProbeErrors:
        """A realistic device, reproducible from ``seed`` (magnitudes in the module doc)."""
        rng = np.random.default_rng([seed, 14])
        return cls(
            force_gain_n_per_bar=_PAPER_GAIN_N_PER_BAR * (1 + 0.005 * rng.standard_normal()),
            force_offset_n=_PAPER_OFFSET_N + 0.01 * rng.standard_normal(),
            # a bend of ~0.025 N RMS over 30-46 kPa
            force_bend_n_per_kpa2=float(rng.choice([-1.0, 1.0]) * abs(0.0012 + 0.0003 * rng.standard_normal())),
            friction_n=float(abs(0.03 + 0.005 * rng.standard_normal())),
            pressure_offset_kpa=0.2 * float(rng.standard_normal()),
            fibre_gain=tuple(float(v) for v in 1 + 0.01 * rng.standard_normal(4)),  # type: ignore[arg-type]
            fibre_bow_mm=tuple(float(v) for v in 0.02 * rng.standard_normal(4)),  # type: ignore[arg-type]
            sps_gap_mm=tuple(float(v) for v in 0.04 * (1 + 0.25 * rng.standard_normal(3)).clip(0.2)),  # type: ignore[arg-type]
            noise_mm=noise_mm,
            seed=seed,
        )

    def as_dict(self) -> dict[str, object]:
        """Plain data for the run's record (the sim driver publishes it latched)."""
        return asdict(self)


class TrueProbe:
    """The device's physics from its error draw: the force the tissue feels, and what the fibres report."""

    def __init__(self, errors: ProbeErrors, stroke_mm: float = 10.0) -> None:
        self.e = errors
        self.stroke_mm = stroke_mm

    def probe_pressure_kpa(self, readback_kpa: ArrayLike) -> ArrayLike:
        """Pressure inside the probe (kPa) when the regulator reads back ``readback_kpa``."""
        p = _f64(readback_kpa) + self.e.pressure_offset_kpa
        return _out(np.clip(p, 0.0, None), readback_kpa)

    def air_force_n(self, probe_kpa: ArrayLike) -> ArrayLike:
        """Force (N) the air pushes the indenter out with, before bore friction; >= 0."""
        p = _f64(probe_kpa)
        f = self.e.force_gain_n_per_bar * p / _BAR_KPA + self.e.force_offset_n
        f = f + self.e.force_bend_n_per_kpa2 * (p - 38.0) ** 2
        return _out(np.clip(f, 0.0, None), probe_kpa)

    def tissue_force_n(self, probe_kpa: ArrayLike, extending: ArrayLike) -> ArrayLike:
        """Force (N) on the tissue: the air force less bore friction while the indenter extends (``extending``
        True), plus it while the tissue pushes the indenter in. Never negative."""
        ext = np.asarray(extending, dtype=bool)
        f = _f64(self.air_force_n(probe_kpa)) + np.where(ext, -1.0, 1.0) * self.e.friction_n
        return _out(np.clip(f, 0.0, None), probe_kpa, extending)

    def sps_gap_mm(self, probe_kpa: ArrayLike) -> FloatArray:
        """(..., 3) air-cushion gaps of SPS1..3 (mm) at the probe pressure: 0 without air."""
        p = np.clip(_f64(probe_kpa), 0.0, None)[..., None]
        gaps: FloatArray = np.asarray(self.e.sps_gap_mm) * np.sqrt(p / _GAP_REF_KPA)
        return gaps

    def fibre_readings_mm(self, true_heights_mm: FloatArray, rng: np.random.Generator | None = None) -> FloatArray:
        """(..., 4) heights the calibrated fibre channels report for true extensions (..., 4): per-channel gain
        error and a bow peaking at mid-stroke, plus white noise. Not clipped to the stroke."""
        h = np.asarray(true_heights_mm, dtype=np.float64)
        s = self.stroke_mm
        bow = np.asarray(self.e.fibre_bow_mm) * 4.0 * (h / s) * (1.0 - h / s)
        out: FloatArray = h * np.asarray(self.e.fibre_gain) + bow
        if rng is not None and self.e.noise_mm > 0:
            out = out + rng.normal(0.0, self.e.noise_mm, out.shape)
        return out

    def eq4_residual_rmse_n(self, lo_kpa: float = 30.0, hi_kpa: float = 46.0) -> float:
        """RMSE (N) of the best straight line through a slow advance-and-retrieve cycle over [lo, hi] kPa: what
        the paper's eq. 4 fit would report for this device (its Fig. 10: < 0.0404 N)."""
        p = np.linspace(lo_kpa, hi_kpa, 200)
        pp = np.concatenate([p, p])
        f = np.concatenate([_f64(self.tissue_force_n(p, False)), _f64(self.tissue_force_n(p, True))])
        keep = f > 0
        coef = np.polyfit(pp[keep], f[keep], 1)
        return float(math.sqrt(np.mean((np.polyval(coef, pp[keep]) - f[keep]) ** 2)))
