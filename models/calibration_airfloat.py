"""Calibrating the air-float probe from what a rig observes (estimator side; pure but for the YAML helpers).

Two steps, as the paper's bench does them (docs/physics.md, "Calibration"):

1. **Force line (eq. 4).** The probe is pressed on a force sensor while the pressure cycles up and down; a
   straight line F = gain * P[bar] + offset is fitted to (read-back pressure, sensor force). The advance/retrieve
   hysteresis and the line's bend stay in the residual (the paper: < 0.0404 N RMSE).
2. **Reference samples.** The probe is held over flat samples of known modulus and measured thickness while the
   pressure ramps; with the force line fixed, a depth offset delta (mm, added to eqs. 1-3's d_in: the SPS air
   gap and any fibre zero error) and a force offset (N) are fitted so that eq. 7 returns the known moduli.

Only rig-observable data enter: read-back pressures, the force sensor, the fibre heights' d_in, the samples'
certified moduli and measured thicknesses. The calibration file (YAML)::

    force: {gain: 7.61, offset: -2.33, pressure_unit_kpa: 100.0}
    depth_offset_mm: -0.041
    residuals: {force_line_rmse_n: 0.037, reference_rms_rel: 0.021}
    source: "free text: when, which samples"
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar

import msgspec
import numpy as np
import numpy.typing as npt
import yaml

from models.airfloat import ForceCalibration
from models.contact import corrected_force
from yamlstruct import Source, convert

__all__ = ["AirfloatCalibration", "CalibrationError", "ReferenceRamp", "fit_force_line", "fit_references",
           "load_calibration", "save_calibration"]


class CalibrationError(ValueError):
    """A calibration file is invalid, or the data cannot determine a calibration."""


@dataclass(frozen=True)
class AirfloatCalibration:
    """What the nodes load: eq. 4's line (pressure controller) and the depth offset (estimator)."""

    force: ForceCalibration = field(default_factory=ForceCalibration)
    depth_offset_mm: float = 0.0
    force_line_rmse_n: float = math.nan
    reference_rms_rel: float = math.nan
    source: str = ""


@dataclass(frozen=True)
class ReferenceRamp:
    """One pressure ramp on a flat reference sample: its certified modulus, its measured thickness, and the
    read-back pressures (kPa) and eqs. 1-3 depths (mm) sampled together."""

    modulus_kpa: float
    thickness_mm: float
    pressure_kpa: npt.NDArray[np.float64]
    d_in_mm: npt.NDArray[np.float64]


def fit_force_line(pressure_kpa: npt.ArrayLike, force_n: npt.ArrayLike,
                   pressure_unit_kpa: float = 100.0) -> tuple[ForceCalibration, float]:
    """Least-squares eq. 4 line through force-sensor data (points with F > 0.01 N); returns it and its RMSE (N)."""
    p = np.asarray(pressure_kpa, dtype=np.float64).ravel()
    f = np.asarray(force_n, dtype=np.float64).ravel()
    keep = np.isfinite(p) & np.isfinite(f) & (f > 0.01)
    if keep.sum() < 10 or np.ptp(p[keep]) < 1.0:
        raise CalibrationError(f"force line: need >= 10 points in contact over >= 1 kPa, got {int(keep.sum())}")
    gain, offset = np.polyfit(p[keep] / pressure_unit_kpa, f[keep], 1)
    rmse = float(np.sqrt(np.mean((gain * p[keep] / pressure_unit_kpa + offset - f[keep]) ** 2)))
    return ForceCalibration(float(gain), float(offset), pressure_unit_kpa), rmse


def fit_references(line: ForceCalibration, ramps: list[ReferenceRamp], *, indenter_radius_mm: float,
                   poisson_ratio: float = 0.5, min_depth_mm: float = 1.0,
                   max_depth_mm: float = 3.2) -> tuple[float, float, float]:
    """(depth offset mm, force offset N, RMS relative force residual) that make eq. 7 return each reference's
    modulus from ``line``'s force and d_in + offset. Only points between ``min_depth_mm`` and ``max_depth_mm`` (the
    paper's 3 mm) count."""
    data = []
    for ramp in ramps:
        p, d = np.asarray(ramp.pressure_kpa, float), np.asarray(ramp.d_in_mm, float)
        keep = np.isfinite(p) & np.isfinite(d) & (d > min_depth_mm) & (d < max_depth_mm)
        if keep.sum() < 10:
            raise CalibrationError(f"reference {ramp.modulus_kpa} kPa: need >= 10 points deeper than "
                                   f"{min_depth_mm} mm, got {int(keep.sum())}")
        f = np.asarray(line.force_n(p[keep]), dtype=np.float64)
        data.append((ramp, f, d[keep]))

    def residual(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        delta, df = x
        out = [f + df - np.asarray(corrected_force(r.modulus_kpa, np.clip(d + delta, 1e-6, None),
                                                   indenter_radius_mm, r.thickness_mm, poisson_ratio))
               for r, f, d in data]
        return np.concatenate(out)

    # absolute force residuals (N): near contact a few hundredths of a newton of hysteresis and regulator
    # wander would dominate relative ones
    # imported here: scipy.optimize costs every estimator and pressure process 0.3 s at start-up, and only the
    # calibration fit (python -m tools.calibrate_airfloat) needs it
    from scipy.optimize import least_squares

    sol = least_squares(residual, x0=[0.0, 0.0], bounds=([-0.5, -0.2], [0.5, 0.2]))
    forces = np.concatenate([f for _, f, _ in data])
    rel = float(np.sqrt(np.mean((sol.fun / np.maximum(forces + sol.x[1], 1e-3)) ** 2)))
    return float(sol.x[0]), float(sol.x[1]), rel


def save_calibration(path: str | Path, cal: AirfloatCalibration) -> None:
    """Write the calibration YAML (module doc)."""
    data = {
        "force": {"gain": round(cal.force.gain, 5), "offset": round(cal.force.offset, 5),
                  "pressure_unit_kpa": cal.force.pressure_unit_kpa},
        "depth_offset_mm": round(cal.depth_offset_mm, 5),
        "residuals": {"force_line_rmse_n": round(cal.force_line_rmse_n, 5),
                      "reference_rms_rel": round(cal.reference_rms_rel, 5)},
        "source": cal.source,
    }
    Path(path).write_text("# air-float probe calibration (docs/physics.md, Calibration)\n"
                          + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


class _CalibrationSource(Source):
    error_type: ClassVar[type[Exception]] = CalibrationError
    document: ClassVar[str] = "the calibration file"


_Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]  # NaN and inf fail


class _ForceDecl(msgspec.Struct, forbid_unknown_fields=True):
    gain: _Finite
    offset: _Finite
    pressure_unit_kpa: _Finite = 100.0


class _ResidualsDecl(msgspec.Struct, forbid_unknown_fields=True):
    force_line_rmse_n: float = math.nan
    reference_rms_rel: float = math.nan


class _CalibrationFile(msgspec.Struct, forbid_unknown_fields=True):
    force: _ForceDecl
    depth_offset_mm: _Finite = 0.0
    residuals: _ResidualsDecl = msgspec.field(default_factory=_ResidualsDecl)
    source: str = ""


def load_calibration(path: str | Path) -> AirfloatCalibration:
    """Read a calibration YAML (module doc) through :mod:`yamlstruct`, the project's one YAML loader.

    Raises:
        CalibrationError: ``file:line:col: key: what is wrong`` (unreadable, malformed, an unknown key, a value
            that is not a finite number, a force line the model refuses).
    """
    src = _CalibrationSource.read(Path(path))
    if not isinstance(src.data, dict):
        raise src.error((), "expected a mapping with force: {gain, offset, pressure_unit_kpa}")
    doc: _CalibrationFile = convert(src, src.data, _CalibrationFile)
    f = doc.force
    try:
        force = ForceCalibration(f.gain, f.offset, f.pressure_unit_kpa)
    except ValueError as exc:
        raise src.error(("force",), f"force: {exc}") from None
    return AirfloatCalibration(force=force, depth_offset_mm=doc.depth_offset_mm,
                               force_line_rmse_n=doc.residuals.force_line_rmse_n,
                               reference_rms_rel=doc.residuals.reference_rms_rel, source=doc.source)
