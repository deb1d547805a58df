"""Inverse of eq. 5 for the multi-indenter camera probe (Faragasso et al., paper 2).

The forward model, the probe geometry and the sign conventions are in ``models.multi_indenter``.

Inverse: substituting ``dt_i = dx_i k_i / K_t`` turns the plane rows of eq. 5 into equations
linear in z = (1/K_t, tan pan, tan tilt) (rows j against the reference indenter a):

    (k_j dx_j - k_a dx_a) / K_t + (x_j - x_a) tan(pan) + (y_j - y_a) tan(tilt) = dx_a - dx_j

Four indenters in contact give three equations: solved in closed form (Cramer, shared by the
single and the batch solver so both give the same floats). With more indenters in contact we
solve the symmetric form ``c - (k_i dx_i)/K_t - x_i tan(pan) - y_i tan(tilt) = dx_i`` (one row
per indenter, c = advance past the surface at the probe origin) by least squares.

The batch solver (an (N, n) array at once) is ``models.multi_indenter_batch``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry, geometry_columns

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "REASONS",
    "StiffnessSolution",
    "solve3",
    "solve_exact",
    "solve_lm",
]

_new_tuple = tuple.__new__

OK, NAN, CONTACT, SATURATED, RIGID, ILL, NONPHYSICAL, LM_FAILED = range(8)
#: Reason text per reason code (index); code 0 means a valid solution.
REASONS: tuple[str, ...] = (
    "ok",
    "marker lost (non-finite displacement)",
    "too few indenters in contact (need 4)",
    "indenter at the end of its stroke",
    "all contacting indenters displaced equally: surface rigid against the springs, K_t unbounded",
    "ill-conditioned system",
    "non-physical solution (K_t <= 0 or not finite)",
    "Levenberg-Marquardt did not converge to a zero residual",
)


def solve3(
    sqrt: Callable[[Any], Any],
    p2: Any,
    p3: Any,
    p4: Any,
    b2: Any,
    b3: Any,
    b4: Any,
    g: Sequence[float],
) -> tuple[Any, ...]:
    """Solve [P X Y] z = B (columns; P the data column, X, Y from ``models.multi_indenter.geometry_columns``) by
    Cramer's rule with triple products; returns (z1, z2, z3, Frobenius condition number of
    the matrix with its columns scaled to unit norm).

    Only + - * / abs and ``sqrt`` are used, so Python floats and numpy arrays give identical
    results (the batch solver, models.multi_indenter_batch, calls it on arrays). With floats a singular system raises ZeroDivisionError (the caller's to catch).
    """
    x2, x3, x4, y2, y3, y4, n2, n3, n4, xx, yy, nn = g
    det = p2 * n2 + p3 * n3 + p4 * n4
    w2, w3, w4 = p3 * b4 - p4 * b3, p4 * b2 - p2 * b4, p2 * b3 - p3 * b2  # W = P x B
    z1 = (b2 * n2 + b3 * n3 + b4 * n4) / det
    z2 = (w2 * y2 + w3 * y3 + w4 * y4) / det
    z3 = -(w2 * x2 + w3 * x3 + w4 * x4) / det
    # Rows of the inverse are N, Y x P, P x X over det; kappa_F(A S^-1) = sqrt(3) |S A^-1|_F
    # with S the column norms; |Y x P|^2 = |Y|^2 |P|^2 - (Y.P)^2 (Lagrange).
    pp = p2 * p2 + p3 * p3 + p4 * p4
    py = p2 * y2 + p3 * y3 + p4 * y4
    px = p2 * x2 + p3 * x3 + p4 * x4
    w = pp * nn + xx * (yy * pp - py * py) + yy * (pp * xx - px * px)
    return z1, z2, z3, sqrt(3.0 * w) / abs(det)


class StiffnessSolution(NamedTuple):
    """One inverse solution (immutable). Invalid results carry NaN numbers and say why.

    ``condition`` is the condition number of the column-equilibrated linear system (Frobenius
    norm for the 3x3 closed form, 2-norm for the least-squares case); NaN when not reached.
    """

    valid: bool
    reason: str
    k_t_n_per_mm: float
    pan_rad: float
    tilt_rad: float
    dt_mm: tuple[float, ...]
    condition: float


def _invalid(code: int, n: int, detail: str = "", condition: float = math.nan) -> StiffnessSolution:
    reason = REASONS[code] + (f": {detail}" if detail else "")
    nan = math.nan
    return StiffnessSolution(False, reason, nan, nan, nan, (nan,) * n, condition)


def _precheck(
    dx_mm: Sequence[float],
    geometry: ProbeGeometry,
    contact_threshold_mm: float,
    equal_tol_mm: float,
) -> StiffnessSolution | tuple[tuple[float, ...], list[int]]:
    """Checks shared by the exact and LM solvers: an invalid result, or (dx, contacting)."""
    dx = tuple(float(v) for v in dx_mm)
    n = geometry.n
    if len(dx) != n:
        raise ValueError(
            f"multi_indenter: expected {n} displacements (one per indenter), got {len(dx)}"
        )
    lost = [i + 1 for i, v in enumerate(dx) if not math.isfinite(v)]
    if lost:
        return _invalid(NAN, n, f"indenter(s) {lost}")
    full = [i + 1 for i, v in enumerate(dx) if v >= geometry.stroke_mm]
    if full:
        return _invalid(SATURATED, n, f"indenter(s) {full} at >= {geometry.stroke_mm} mm")
    touching = [i for i, v in enumerate(dx) if v > contact_threshold_mm]
    if len(touching) < 4:
        ids = [i + 1 for i in touching]
        return _invalid(CONTACT, n, f"{ids} moved more than {contact_threshold_mm} mm")
    ref = dx[touching[0]]
    if all(abs(dx[i] - ref) <= equal_tol_mm for i in touching):
        return _invalid(RIGID, n, f"dx = {ref:.6g} mm")
    return dx, touching


def _linear_solve(
    dx: tuple[float, ...], touching: list[int], geometry: ProbeGeometry
) -> tuple[float, float, float, float]:
    """(1/K_t, tan pan, tan tilt, condition); condition is inf for a singular system."""
    x, y, k = geometry.x_mm, geometry.y_mm, geometry.k_n_per_mm
    if len(touching) == 4:
        ia, *rest = touching
        p = [k[j] * dx[j] - k[ia] * dx[ia] for j in rest]
        b = [dx[ia] - dx[j] for j in rest]
        try:
            u, tp, tt, cond = solve3(
                math.sqrt, p[0], p[1], p[2], b[0], b[1], b[2], geometry_columns(x, y, touching)
            )
        except ZeroDivisionError:
            return math.nan, math.nan, math.nan, math.inf
        return float(u), float(tp), float(tt), float(cond)
    idx = np.asarray(touching)
    d = np.asarray(dx)[idx]
    mat = np.column_stack(
        [np.ones(len(idx)), -np.asarray(k)[idx] * d, -np.asarray(x)[idx], -np.asarray(y)[idx]]
    )
    scale = np.linalg.norm(mat, axis=0)
    if not np.all(scale > 0):
        return math.nan, math.nan, math.nan, math.inf
    z, _, rank, sv = np.linalg.lstsq(mat / scale, d, rcond=None)
    if rank < 4:
        return math.nan, math.nan, math.nan, math.inf
    z = z / scale
    return float(z[1]), float(z[2]), float(z[3]), float(sv[0] / sv[-1])


def _finish(
    u: float,
    tp: float,
    tt: float,
    cond: float,
    dx: tuple[float, ...],
    touching: list[int],
    geometry: ProbeGeometry,
    max_condition: float,
) -> StiffnessSolution:
    n = geometry.n
    if not (cond <= max_condition):
        return _invalid(ILL, n, f"condition {cond:.3g} > {max_condition:.3g}", cond)
    if not (u > 0 and math.isfinite(u) and math.isfinite(tp) and math.isfinite(tt)):
        return _invalid(NONPHYSICAL, n, f"1/K_t = {u:.6g} mm/N", cond)
    on = set(touching)
    k = geometry.k_n_per_mm
    dt = tuple(dx[i] * k[i] * u if i in on else 0.0 for i in range(n))
    return StiffnessSolution(True, REASONS[OK], 1.0 / u, math.atan(tp), math.atan(tt), dt, cond)


def solve_exact(
    dx_mm: Sequence[float],
    geometry: ProbeGeometry = PAPER_GEOMETRY,
    *,
    contact_threshold_mm: float = 0.05,
    max_condition: float = 1e4,
    equal_tol_mm: float = 1e-9,
) -> StiffnessSolution:
    """Tissue stiffness K_t (N/mm), pan/tilt (rad) and dt (mm) from indenter displacements (mm).

    An indenter is in contact when it moved more than ``contact_threshold_mm`` (0.05 mm is
    about 0.6 px at 12.7 px/mm, twice the raw centroid noise). Needs >= 4 in contact; exactly
    4 use the closed form, more use least squares (numpy lstsq). Invalid results (never an
    exception for bad data): lost marker, end of stroke, too few contacts, all displacements
    equal, condition > ``max_condition``, K_t <= 0.
    """
    # Lists and tuples are used as they are (the arithmetic accepts any real numbers).
    dx = dx_mm.tolist() if isinstance(dx_mm, np.ndarray) else dx_mm
    if len(dx) == 4 == geometry.n:
        # Fast path, the common case: all four in contact and inside their stroke (NaN fails
        # every comparison). Anything unusual falls through to the general path below,
        # which repeats the checks and says what is wrong.
        d1, d2, d3, d4 = dx
        lo, hi = contact_threshold_mm, geometry.stroke_mm
        if lo < d1 < hi and lo < d2 < hi and lo < d3 < hi and lo < d4 < hi:
            k1, k2, k3, k4 = geometry.k_n_per_mm
            f1 = k1 * d1
            b2, b3, b4 = d1 - d2, d1 - d3, d1 - d4
            try:
                u, tp, tt, cond = solve3(
                    math.sqrt, k2 * d2 - f1, k3 * d3 - f1, k4 * d4 - f1, b2, b3, b4, geometry.columns
                )
            except ZeroDivisionError:
                u = tp = tt = cond = math.nan
            if (
                cond <= max_condition
                and 0.0 < u < math.inf
                and -math.inf < tp < math.inf
                and -math.inf < tt < math.inf
                and not (
                    -equal_tol_mm <= b2 <= equal_tol_mm
                    and -equal_tol_mm <= b3 <= equal_tol_mm
                    and -equal_tol_mm <= b4 <= equal_tol_mm
                )
            ):
                dt = (d1 * k1 * u, d2 * k2 * u, d3 * k3 * u, d4 * k4 * u)
                # tuple.__new__ skips the NamedTuple's Python-level __new__ (about 0.5 us of
                # the ~3 us this path takes); the object is the same.
                return _new_tuple(
                    StiffnessSolution, (True, "ok", 1.0 / u, math.atan(tp), math.atan(tt), dt, cond)
                )
    pre = _precheck(dx, geometry, contact_threshold_mm, equal_tol_mm)
    if isinstance(pre, StiffnessSolution):
        return pre
    dx_t, touching = pre
    u, tp, tt, cond = _linear_solve(dx_t, touching, geometry)
    return _finish(u, tp, tt, cond, dx_t, touching, geometry, max_condition)


def solve_lm(
    dx_mm: Sequence[float],
    geometry: ProbeGeometry = PAPER_GEOMETRY,
    *,
    contact_threshold_mm: float = 0.05,
    max_condition: float = 1e4,
    equal_tol_mm: float = 1e-9,
    k_t_guess_n_per_mm: float | None = None,
    tol: float = 1e-14,
    max_residual: float = 1e-9,
) -> StiffnessSolution:
    """The paper's way: Levenberg-Marquardt (scipy, MINPACK) on the rows of eq. 5.

    Unknowns dt_i (contacting indenters), pan, tilt, K_t; start at pan = tilt = 0 and K_t =
    ``k_t_guess_n_per_mm`` (default: the stiffest probe spring). Same validity checks as
    :func:`solve_exact` (its condition number is reported too), plus LM failure: no
    convergence or a final residual norm above ``max_residual`` (N and mm mixed, as eq. 5).
    """
    pre = _precheck(dx_mm, geometry, contact_threshold_mm, equal_tol_mm)
    if isinstance(pre, StiffnessSolution):
        return pre
    dx, touching = pre
    n, m = geometry.n, len(touching)
    cond = _linear_solve(dx, touching, geometry)[3]
    if not (cond <= max_condition):
        return _invalid(ILL, n, f"condition {cond:.3g} > {max_condition:.3g}", cond)
    idx = np.asarray(touching)
    d = np.asarray(dx)[idx]
    kk = np.asarray(geometry.k_n_per_mm)[idx]
    ddx = np.asarray(geometry.x_mm)[idx][1:] - geometry.x_mm[touching[0]]
    ddy = np.asarray(geometry.y_mm)[idx][1:] - geometry.y_mm[touching[0]]
    kd = kk * d
    jac = np.zeros((2 * m - 1, m + 3))
    rows = np.arange(m)
    jac[m + rows[:-1], 1 + rows[:-1]] = 1.0
    jac[m:, 0] = -1.0

    def fun(p: FloatArray) -> FloatArray:
        dt, th, al, kt = p[:m], p[m], p[m + 1], p[m + 2]
        s = d + dt
        plane = s[1:] - s[0] + math.tan(th) * ddx + math.tan(al) * ddy
        return np.concatenate([kd - kt * dt, plane])

    def jacobian(p: FloatArray) -> FloatArray:
        jac[rows, rows] = -p[m + 2]
        jac[rows, m + 2] = -p[:m]
        jac[m:, m] = ddx / math.cos(p[m]) ** 2
        jac[m:, m + 1] = ddy / math.cos(p[m + 1]) ** 2
        return jac.copy()

    kt0 = max(geometry.k_n_per_mm) if k_t_guess_n_per_mm is None else k_t_guess_n_per_mm
    p0 = np.concatenate([kd / kt0, [0.0, 0.0, kt0]])
    # imported here: scipy.optimize costs ~0.1 s at start-up, and every process importing the estimator paid it
    # (the air-float estimator never calls this)
    from scipy.optimize import least_squares

    res = least_squares(fun, p0, jac=jacobian, method="lm", xtol=tol, ftol=tol, gtol=tol)
    resid = float(np.linalg.norm(res.fun))
    if not (res.status > 0 and resid <= max_residual):
        return _invalid(LM_FAILED, n, f"status {res.status}, |F| = {resid:.3g}", cond)
    kt = float(res.x[m + 2])
    if not (kt > 0 and math.isfinite(kt)):
        return _invalid(NONPHYSICAL, n, f"K_t = {kt:.6g} N/mm", cond)
    dt_all = [0.0] * n
    for pos, i in enumerate(touching):
        dt_all[i] = float(res.x[pos])
    # LM works on the angles themselves; fold them into (-pi/2, pi/2) like the exact solve.
    pan, tilt = math.atan(math.tan(res.x[m])), math.atan(math.tan(res.x[m + 1]))
    return StiffnessSolution(True, REASONS[OK], kt, pan, tilt, tuple(dt_all), cond)
