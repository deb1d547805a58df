"""Calibrating the camera probe from what a rig observes (issue 14, item 6): the fits and the file.

The procedure (``tools/camera_calibrate.py`` runs it; docs/camera.md "Calibration"): the linear
stage presses the probe, flat and slowly, into references and back out while the camera tracker
publishes each marker's filtered image x. Observed: the stage's travel t (mm, from the pose), its
direction of motion, each marker's pixel offset u = direction * (x - x_rest) from its zero
reference. Known: that the first reference is rigid, and each further reference's label K.

1. **Rigid flat** (a block far stiffer than the springs): every indenter moves with the stage once
   it touches, dx_i = t - t_c. Regressing t on u gives, per marker, t = t_c + c1 u + c2 u^2 +
   c3 u^3 (+ a term in the direction of motion that takes the Kalman filter's lag): the
   polynomial is that marker's pixel -> mm map, its own scale and the lens's distortion along its
   path included; the intercept is the contact travel.
2. **Reference springs** of known K: with the map, dx_i is known in mm; in full contact
   dx_i = K (t - t_c) / (k_i + K) -/+ f_i / (k_i + K) (guide friction and filter lag flip with the
   direction of motion), so the slope s_i of dx_i against t gives k_i = K (1 / s_i - 1). Slopes do
   not see the contact offset, friction or lag. Each reference gives one k_i; the file keeps their
   mean.

Pure: arrays in, numbers out; the file is read by :func:`load_probe_calibration` through :mod:`yamlstruct` (the
project's one YAML loader) and written by the node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import msgspec
import numpy as np
import numpy.typing as npt

from models.tracker import poly_to_mm
from yamlstruct import Source, convert

FloatArray = npt.NDArray[np.float64]

__all__ = ["CalibrationError", "ProbeCalibration", "fit_scale", "fit_springs", "load_probe_calibration"]


class CalibrationError(ValueError):
    """A calibration cannot be fitted or read; the message says which marker or key and why."""


@dataclass(frozen=True)
class ProbeCalibration:
    """A probe's calibration: per-marker pixel -> mm polynomials and per-indenter spring constants.

    scale_poly[j]: (c1, c2, c3) of d_mm = c1 u + c2 u^2 + c3 u^3, u = direction * (x - rest) px;
    k_n_per_mm: the identified spring constants (indenter order); info: provenance (free form).
    """

    scale_poly: tuple[tuple[float, ...], ...]
    k_n_per_mm: tuple[float, ...]
    direction: float = 1.0
    info: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if len(self.scale_poly) != len(self.k_n_per_mm) or not self.scale_poly:
            raise CalibrationError(f"calibration: {len(self.scale_poly)} scale polynomials for "
                                   f"{len(self.k_n_per_mm)} springs")
        if not all(k > 0 and math.isfinite(k) for k in self.k_n_per_mm):
            raise CalibrationError(f"calibration: spring constants must be finite and > 0, got {self.k_n_per_mm}")
        for j, p in enumerate(self.scale_poly):
            if not p or not all(math.isfinite(c) for c in p) or not p[0] > 0:
                raise CalibrationError(f"calibration: scale_poly[{j}] must be finite with c1 > 0, got {p}")
        if self.direction not in (1.0, -1.0):
            raise CalibrationError(f"calibration: direction must be +1 or -1, got {self.direction}")

    def to_dict(self) -> dict[str, Any]:
        """Plain values for the YAML file."""
        return {"scale_poly": [list(p) for p in self.scale_poly], "k_n_per_mm": list(self.k_n_per_mm),
                "direction": self.direction, "info": dict(self.info)}

    @classmethod
    def from_dict(cls, doc: Any, source: str = "<calibration>") -> ProbeCalibration:
        """Read a calibration file's contents; errors name ``source`` and the key."""
        return _probe_calibration(_CalibrationSource(path=Path(source), name=source, data=doc))

    def to_mm(self, u_px: npt.ArrayLike) -> FloatArray:
        """Displacements (mm) for pixel offsets u (..., n) from the zero reference."""
        return poly_to_mm(u_px, self.scale_poly)


class _CalibrationSource(Source):
    error_type: ClassVar[type[Exception]] = CalibrationError
    document: ClassVar[str] = "the calibration file"


class _CalibrationFile(msgspec.Struct, forbid_unknown_fields=True):
    scale_poly: list[list[float]]
    k_n_per_mm: list[float]
    direction: float = 1.0
    info: dict[str, Any] | None = None


def _probe_calibration(src: Source) -> ProbeCalibration:
    if not isinstance(src.data, dict):
        raise src.error((), "expected a mapping with scale_poly and k_n_per_mm")
    doc: _CalibrationFile = convert(src, src.data, _CalibrationFile)
    try:
        return ProbeCalibration(tuple(tuple(p) for p in doc.scale_poly), tuple(doc.k_n_per_mm), doc.direction,
                                dict(doc.info or {}))
    except CalibrationError as exc:
        text = str(exc).removeprefix("calibration: ")
        where = ("direction",) if "direction" in text else ("scale_poly",) if "scale_poly" in text else ("k_n_per_mm",)
        raise src.error(where, text) from None


def load_probe_calibration(path: str | Path) -> ProbeCalibration:
    """Read a camera-probe calibration file (``tools/camera_calibrate.py`` writes it).

    Raises:
        CalibrationError: ``file:line:col: what is wrong`` (unreadable, malformed, an unknown or missing key, a
            wrong type, or values the calibration cannot hold).
    """
    return _probe_calibration(_CalibrationSource.read(Path(path)))


def fit_scale(travel_mm: npt.ArrayLike, u_px: npt.ArrayLike, direction: npt.ArrayLike,
              *, min_u_px: float = 20.0, degree: int = 3) -> tuple[tuple[tuple[float, ...], ...], FloatArray]:
    """Per-marker pixel -> mm polynomials from a rigid-flat press: (polys, contact travel per marker).

    travel_mm (N,): stage travel; u_px (N, n): pixel offsets; direction (N,): +1 pressing, -1
    releasing, 0 holding (holds are skipped). Samples with u < ``min_u_px`` (the knee, where the
    filter has not settled to the stage's speed) are skipped.
    """
    t = np.asarray(travel_mm, dtype=np.float64)
    u = np.asarray(u_px, dtype=np.float64)
    d = np.sign(np.asarray(direction, dtype=np.float64))
    polys, contact = [], []
    for j in range(u.shape[1]):
        use = (u[:, j] > min_u_px) & (d != 0) & np.isfinite(u[:, j])
        if use.sum() < 4 * (degree + 2) or not ((d[use] > 0).any() and (d[use] < 0).any()):
            raise CalibrationError(f"rigid-flat fit: marker {j + 1} has {int(use.sum())} samples in contact "
                                   "(need a press and a release past the knee)")
        uj = u[use, j]
        cols = [np.ones_like(uj), d[use]] + [uj ** (m + 1) for m in range(degree)]
        coef, *_ = np.linalg.lstsq(np.column_stack(cols), t[use], rcond=None)
        contact.append(coef[0])
        polys.append(tuple(float(c) for c in coef[2:]))
    return tuple(polys), np.asarray(contact)


def fit_springs(travel_mm: npt.ArrayLike, dx_mm: npt.ArrayLike, direction: npt.ArrayLike, k_ref_n_per_mm: float,
                *, min_dx_mm: float = 1.0, max_dx_mm: float = 9.0,
                scale_slope_error: float = 0.002) -> tuple[FloatArray, FloatArray]:
    """Spring constants (N/mm, per indenter) and their standard errors from a press of a reference of known K.

    Regresses dx_i = s_i t + b_i + c_i sign(motion) over samples in full contact, stage moving,
    and returns K (1 / s_i - 1). Full contact is chosen on the stage travel (where a first fit
    puts dx between ``min_dx`` and ``max_dx`` mm), never on the noisy dx itself, which would bias
    the slope. The standard error adds the pixel -> mm map's own slope error (relative,
    ``scale_slope_error``: about 0.2 % for the rigid-flat cubic) to the regression's: k = K (1/s - 1)
    magnifies a slope error by K / s^2, so a reference much stiffer than a spring says little
    about it, and the weighted mean leans on the reference that suits each spring.
    """
    if not (k_ref_n_per_mm > 0 and math.isfinite(k_ref_n_per_mm)):
        raise CalibrationError(f"reference spring: K must be finite and > 0, got {k_ref_n_per_mm}")
    t = np.asarray(travel_mm, dtype=np.float64)
    dx = np.asarray(dx_mm, dtype=np.float64)
    d = np.sign(np.asarray(direction, dtype=np.float64))
    k_out, se_out = np.empty(dx.shape[1]), np.empty(dx.shape[1])
    for j in range(dx.shape[1]):
        use = (dx[:, j] > min_dx_mm) & (dx[:, j] < max_dx_mm) & (d != 0)
        for _ in range(2):
            if use.sum() < 20 or not ((d[use] > 0).any() and (d[use] < 0).any()):
                raise CalibrationError(f"reference {k_ref_n_per_mm} N/mm: indenter {j + 1} has {int(use.sum())} "
                                       f"samples with {min_dx_mm} < dx < {max_dx_mm} mm (need a press and a release)")
            a = np.column_stack([t[use], np.ones(int(use.sum())), d[use]])
            coef, *_ = np.linalg.lstsq(a, dx[use, j], rcond=None)
            s, b = float(coef[0]), float(coef[1])
            if not 0 < s < 1:
                raise CalibrationError(f"reference {k_ref_n_per_mm} N/mm: indenter {j + 1} slope {s:.4f} "
                                       "outside (0, 1)")
            fitted, use = use, (t > (min_dx_mm - b) / s) & (t < (max_dx_mm - b) / s) & (d != 0)
        resid = dx[fitted, j] - a @ coef
        cov = np.linalg.inv(a.T @ a) * float(resid @ resid) / max(len(resid) - 3, 1)
        k_out[j] = k_ref_n_per_mm * (1.0 / s - 1.0)
        se_out[j] = k_ref_n_per_mm / (s * s) * math.sqrt(max(float(cov[0, 0]), 0.0) + (scale_slope_error * s) ** 2)
    return k_out, se_out
