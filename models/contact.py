"""Indentation contact mechanics of a spherical indenter (air-float paper, eqs. 5-8).

Units throughout: force F in N, indentation depth d, indenter radius r and sample thickness in mm,
Young's modulus E in kPa. The papers' equations are in consistent SI-like units, so a modulus
computed from N and mm comes out in N/mm^2 = MPa; every function converts with ``_KPA_PER_N_MM2``.

Every model here is *linear in E* for a fixed depth: F = E * g(d). The inverse functions are
therefore E = F / g(d), the forward functions F = E * g(d), and fitting a force-depth curve for E
is a one-parameter linear least squares problem (Fung's exponent b needs a 1-D search on top).

All functions accept floats or numpy arrays (broadcast together) and return a float when every
argument is a scalar. Where d <= 0 (no contact) the inverse functions return nan and the forward
functions return 0.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from models._arrays import ArrayLike, FloatArray
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out

_KPA_PER_N_MM2 = 1000.0  # 1 N/mm^2 = 1 MPa = 1000 kPa

# Dimitriadis et al. (2002) correction for a sample bonded to a rigid substrate (eq. 7).
DIMITRIADIS_COEFFS: tuple[float, ...] = (1.0, 1.133, 1.283, 0.769, 0.0975)

# Bounds for Fung's nonlinearity exponent b in fit_force_depth. Over the paper's range
# (d <= 3 mm, r = 4 mm) the bracket in the exponent is ~0.1, so |b| = 30 already scales the force
# by e^3: wider bounds would only let noise run away.
FUNG_B_BOUNDS: tuple[float, float] = (-30.0, 30.0)




def _check_positive(name: str, value: ArrayLike, unit: str = "mm") -> None:
    v = _f64(value)
    if not np.all(np.isfinite(v) & (v > 0)):
        raise ValueError(f"contact: {name} must be finite and > 0 ({unit}), got {value!r}")


def _check_nu(nu: float) -> None:
    if not (0.0 <= nu <= 0.5):
        raise ValueError(f"contact: poisson ratio nu must be in [0, 0.5], got {nu!r}")


# --------------------------------------------------------------------------- shape functions
# g(d) such that F [N] = E [kPa] * g(d) [N/kPa]. Zero where d <= 0.


def _hertz_g(d: FloatArray, r: FloatArray, nu: float) -> FloatArray:
    dp = np.clip(d, 0.0, None)
    # eq. 6 solved for F: F = 8 E d sqrt(r d) / (6 (1 - nu^2)), E in N/mm^2.
    g: FloatArray = 8.0 * dp * np.sqrt(r * dp) / (6.0 * (1.0 - nu**2)) / _KPA_PER_N_MM2
    return g


def thickness_correction(d: ArrayLike, r: ArrayLike, thickness: ArrayLike) -> ArrayLike:
    """Dimitriadis factor of eq. 7: 1 + 1.133chi + 1.283chi^2 + 0.769chi^3 + 0.0975chi^4.

    chi = sqrt(r d) / thickness (all mm) is the contact radius over the sample thickness. The
    factor is >= 1: a thin sample bonded to a rigid table pushes back harder than a half-space,
    so plain Hertz (eq. 6) over-estimates E by exactly this factor.
    """
    _check_positive("thickness", thickness)
    dd, rr, tt = _f64(d), _f64(r), _f64(thickness)
    chi = np.sqrt(rr * np.clip(dd, 0.0, None)) / tt
    poly = np.asarray(np.polynomial.polynomial.polyval(chi, DIMITRIADIS_COEFFS), dtype=np.float64)
    return _out(poly, d, r, thickness)


def _fung_g(d: FloatArray, r: FloatArray, b: FloatArray, nu: float) -> FloatArray:
    dp = np.clip(d, 0.0, None)
    t = np.sqrt(r * dp)  # eq. 5
    # eq. 8 exactly as printed (the pi cancels); both denominators are -(5r - t) powers, so
    # they never vanish for t < 5r, i.e. d < 25 r.
    poly = (t**5 - 15 * r * t**4 + 75 * r**2 * t**3) / (5 * r * t**2 - 50 * r**2 * t + 125 * r**3)
    expo = b * (t**3 - 15 * r * t**2) / (25 * r**2 * t - 125 * r**3)
    g: FloatArray = 20.0 * np.pi / (9.0 * np.pi * (1.0 - nu**2)) * poly * np.exp(expo)
    return g / _KPA_PER_N_MM2


def _modulus(force: ArrayLike, g: FloatArray) -> FloatArray:
    with np.errstate(divide="ignore", invalid="ignore"):
        e: FloatArray = np.where(g > 0, _f64(force) / np.where(g > 0, g, 1.0), np.nan)
    return e


# --------------------------------------------------------------------------- Hertz, eq. 6


def hertz_modulus(
    force_n: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, nu: float = 0.5
) -> ArrayLike:
    """Young's modulus (kPa) from a force (N) at indentation depth d (mm), Hertz half-space, eq. 6.

    E = 6 F (1 - nu^2) / (8 d sqrt(r d)). Valid when the sample is thick compared with the
    indenter (thickness/r > 10); over-estimates thin samples (see ``corrected_modulus``).
    nan where d <= 0.
    """
    _check_positive("r", r_mm)
    _check_nu(nu)
    return _out(_modulus(force_n, _hertz_g(_f64(d_mm), _f64(r_mm), nu)), force_n, d_mm, r_mm)


def hertz_force(e_kpa: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, nu: float = 0.5) -> ArrayLike:
    """Indentation force (N) of a sphere of radius r (mm) pressed d (mm) into a half-space of E (kPa), eq. 6."""
    _check_positive("r", r_mm)
    _check_nu(nu)
    return _out(_f64(e_kpa) * _hertz_g(_f64(d_mm), _f64(r_mm), nu), e_kpa, d_mm, r_mm)


def hertz_depth(
    force_n: ArrayLike, e_kpa: ArrayLike, r_mm: ArrayLike, nu: float = 0.5
) -> ArrayLike:
    """Indentation depth (mm) reached under force F (N) on a half-space of E (kPa): eq. 6 inverted.

    d = (3 F (1 - nu^2) / (4 E sqrt(r)))^(2/3); 0 where F <= 0.
    """
    _check_positive("r", r_mm)
    _check_positive("E", e_kpa, "kPa")
    _check_nu(nu)
    f = np.clip(_f64(force_n), 0.0, None)
    e = _f64(e_kpa) / _KPA_PER_N_MM2
    d = (3.0 * f * (1.0 - nu**2) / (4.0 * e * np.sqrt(_f64(r_mm)))) ** (2.0 / 3.0)
    return _out(d, force_n, e_kpa, r_mm)


# --------------------------------------------------------------------------- eq. 7


def corrected_modulus(
    force_n: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, thickness_mm: ArrayLike, nu: float = 0.5
) -> ArrayLike:
    """Young's modulus (kPa) of a sample of finite thickness bonded to a rigid base, eq. 7.

    Hertz (eq. 6) divided by the Dimitriadis polynomial in chi = sqrt(r d)/thickness. Use it for
    thickness/r < 10 (the paper's 20 mm samples with r = 4 mm). nan where d <= 0.
    """
    _check_positive("r", r_mm)
    _check_nu(nu)
    dd, rr = _f64(d_mm), _f64(r_mm)
    g = _hertz_g(dd, rr, nu) * _f64(thickness_correction(dd, rr, thickness_mm))
    return _out(_modulus(force_n, g), force_n, d_mm, r_mm, thickness_mm)


def corrected_force(
    e_kpa: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, thickness_mm: ArrayLike, nu: float = 0.5
) -> ArrayLike:
    """Force (N) of a sphere (r, mm) pressed d (mm) into a bonded sample of E (kPa) and thickness (mm), eq. 7."""
    _check_positive("r", r_mm)
    _check_nu(nu)
    dd, rr = _f64(d_mm), _f64(r_mm)
    g = _hertz_g(dd, rr, nu) * _f64(thickness_correction(dd, rr, thickness_mm))
    return _out(_f64(e_kpa) * g, e_kpa, d_mm, r_mm, thickness_mm)


def corrected_depth(
    force_n: ArrayLike,
    e_kpa: ArrayLike,
    r_mm: ArrayLike,
    thickness_mm: ArrayLike,
    nu: float = 0.5,
    tol_mm: float = 1e-12,
) -> ArrayLike:
    """Depth (mm) at which eq. 7 gives force F (N): what a simulator needs to turn a force into d.

    F(d) is strictly increasing, so Newton's method from the Hertz depth (an upper bound, since
    the correction factor is >= 1) converges monotonically. 0 where F <= 0.
    """
    _check_positive("r", r_mm)
    _check_positive("E", e_kpa, "kPa")
    _check_positive("thickness", thickness_mm)
    _check_nu(nu)
    f = np.clip(_f64(force_n), 0.0, None)
    e, r, t = _f64(e_kpa), _f64(r_mm), _f64(thickness_mm)
    d = np.asarray(_f64(hertz_depth(f, e, r, nu)), dtype=np.float64)
    c = np.asarray(DIMITRIADIS_COEFFS)
    dc = c[1:] * np.arange(1, len(c))  # coefficients of the polynomial's derivative
    for _ in range(60):
        dp = np.clip(d, 1e-300, None)
        chi = np.sqrt(r * dp) / t
        poly = np.polynomial.polynomial.polyval(chi, c)
        dpoly = np.polynomial.polynomial.polyval(chi, dc)
        g = _hertz_g(dp, r, nu)
        # d/dd [g * poly]: g ~ d^1.5, chi ~ d^0.5
        slope = g * (1.5 * poly + 0.5 * chi * dpoly) / dp
        with np.errstate(divide="ignore", invalid="ignore"):  # F = 0 rows are masked out
            step = np.where(f > 0, (e * g * poly - f) / (e * slope), 0.0)
        d = np.where(f > 0, d - step, 0.0)
        if np.all(np.abs(step) <= tol_mm):
            break
    return _out(d, force_n, e_kpa, r_mm, thickness_mm)


# --------------------------------------------------------------------------- Fung, eq. 8


def fung_modulus(
    force_n: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, b: ArrayLike = 0.0, nu: float = 0.5
) -> ArrayLike:
    """Young's modulus (kPa) from eq. 8 (Fung hyperelastic sphere, t = sqrt(r d)) for a given b.

    b is Fung's dimensionless nonlinearity exponent (get it from ``fit_force_depth``); b = 0 is
    not plain Hertz but agrees with it to first order in small t/r. nan where d <= 0.
    """
    _check_positive("r", r_mm)
    _check_nu(nu)
    g = _fung_g(_f64(d_mm), _f64(r_mm), _f64(b), nu)
    return _out(_modulus(force_n, g), force_n, d_mm, r_mm, b)


def fung_force(
    e_kpa: ArrayLike, d_mm: ArrayLike, r_mm: ArrayLike, b: ArrayLike = 0.0, nu: float = 0.5
) -> ArrayLike:
    """Force (N) from eq. 8 for modulus E (kPa), depth d (mm), indenter radius r (mm) and exponent b."""
    _check_positive("r", r_mm)
    _check_nu(nu)
    g = _fung_g(_f64(d_mm), _f64(r_mm), _f64(b), nu)
    return _out(_f64(e_kpa) * g, e_kpa, d_mm, r_mm, b)


# --------------------------------------------------------------------------- curve fitting


class FitResiduals(NamedTuple):
    """Root-mean-square force residual (N) of each fitted model over the points used."""

    hertz: float
    corrected: float
    fung: float


class FitResult(NamedTuple):
    """Moduli (kPa) fitted to one force-depth curve by each contact model."""

    E_hertz: float
    E_corrected: float
    E_fung: float
    b_fung: float
    residuals: FitResiduals


def _ls_modulus(f: FloatArray, g: FloatArray) -> tuple[float, float]:
    """Least-squares E for F = E g (no intercept) and the RMS residual."""
    e = float(np.dot(f, g) / np.dot(g, g))
    return e, float(np.sqrt(np.mean((f - e * g) ** 2)))


def fit_force_depth(
    force_n: npt.ArrayLike,
    d_mm: npt.ArrayLike,
    r_mm: float,
    thickness_mm: float,
    nu: float = 0.5,
) -> FitResult:
    """Fit a whole force-depth curve (e.g. one pressure ramp) with eqs. 6, 7 and 8.

    Points with d <= 0 (not yet in contact) are dropped. E for eqs. 6 and 7 is the linear least
    squares solution of F = E g(d) through the origin; for eq. 8 the E that is optimal for a given
    b is solved in closed form and b is found by a bounded 1-D search (``FUNG_B_BOUNDS``), i.e.
    variable projection. Raises ValueError when fewer than 1 (2 for Fung) points are in contact.
    """
    f = np.asarray(force_n, dtype=np.float64).ravel()
    d = np.asarray(d_mm, dtype=np.float64).ravel()
    if f.shape != d.shape:
        raise ValueError(
            f"fit_force_depth: force_n and d_mm differ in length ({f.size} vs {d.size})"
        )
    _check_positive("r", r_mm)
    _check_positive("thickness", thickness_mm)
    _check_nu(nu)
    keep = np.isfinite(f) & np.isfinite(d) & (d > 0)
    f, d = f[keep], d[keep]
    if f.size < 2:
        raise ValueError(f"fit_force_depth: need >= 2 finite points with d > 0, got {f.size}")
    r = _f64(r_mm)
    g_h = _hertz_g(d, r, nu)
    e_h, res_h = _ls_modulus(f, g_h)
    g_c = g_h * _f64(thickness_correction(d, r, thickness_mm))
    e_c, res_c = _ls_modulus(f, g_c)

    def fung_rms(b: float) -> float:
        return _ls_modulus(f, _fung_g(d, r, _f64(b), nu))[1]

    # The RMS need not be unimodal in b: locate the best cell of a coarse grid, then refine in it.
    grid = np.linspace(*FUNG_B_BOUNDS, 61)
    i = int(np.argmin([fung_rms(float(b)) for b in grid]))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    # imported here: the fit is offline, and every estimator process imports this module
    from scipy.optimize import minimize_scalar

    opt = minimize_scalar(fung_rms, bounds=(lo, hi), method="bounded", options={"xatol": 1e-7})
    b = float(opt.x)
    e_f, res_f = _ls_modulus(f, _fung_g(d, r, _f64(b), nu))
    return FitResult(e_h, e_c, e_f, b, FitResiduals(res_h, res_c, res_f))
