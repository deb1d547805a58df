"""The batch inverse of eq. 5 for the multi-indenter camera probe: :func:`solve_batch` is
:func:`models.multi_indenter_solve.solve_exact` over an (N, n) array of displacements, vectorised, with its
results in a :class:`BatchSolution` of arrays.

Samples are grouped by contact pattern; four contacts use the same closed form as the single solve
(``models.multi_indenter_solve.solve3``, so both give the same floats), more use stacked SVD least squares.
Split from models.multi_indenter_solve, which holds the single-sample solvers, the reason codes and the
closed form.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry, geometry_columns
from models.multi_indenter_solve import (
    CONTACT,
    ILL,
    NAN,
    NONPHYSICAL,
    OK,
    REASONS,
    RIGID,
    SATURATED,
    BoolArray,
    FloatArray,
    solve3,
)

__all__ = ["BatchSolution", "solve_batch"]


class BatchSolution(NamedTuple):
    """Vectorised solutions for N samples; ``reason_code`` indexes ``REASONS``."""

    valid: BoolArray  # (N,)
    reason_code: npt.NDArray[np.int8]  # (N,)
    k_t_n_per_mm: FloatArray  # (N,)
    pan_rad: FloatArray  # (N,)
    tilt_rad: FloatArray  # (N,)
    dt_mm: FloatArray  # (N, n)
    condition: FloatArray  # (N,)

    def reason(self, i: int) -> str:
        """Reason text for sample ``i``."""
        return REASONS[int(self.reason_code[i])]


def solve_batch(
    dx_mm: npt.ArrayLike,
    geometry: ProbeGeometry = PAPER_GEOMETRY,
    *,
    contact_threshold_mm: float = 0.05,
    max_condition: float = 1e4,
    equal_tol_mm: float = 1e-9,
) -> BatchSolution:
    """:func:`solve_exact` over an (N, n) array of displacements (mm), vectorised.

    Samples are grouped by contact pattern (at most 2**n groups, one numpy pass each, no
    loop per sample). Four contacts: the same closed form with the same floats as the
    single solve; more: stacked SVD least squares (agrees with lstsq to rounding).
    """
    dx = np.asarray(dx_mm, dtype=np.float64)
    n = geometry.n
    if dx.ndim != 2 or dx.shape[1] != n:
        raise ValueError(
            f"solve_batch: expected an (N, {n}) array of displacements, got shape {dx.shape}"
        )
    big_n = dx.shape[0]
    code = np.full(big_n, OK, dtype=np.int8)
    u = np.full(big_n, np.nan)
    tp = np.full(big_n, np.nan)
    tt = np.full(big_n, np.nan)
    cond = np.full(big_n, np.nan)
    # Work on columns: numpy reductions along a short last axis are slow.
    cols = [np.ascontiguousarray(dx[:, i]) for i in range(n)]
    finite = np.ones(big_n, dtype=bool)
    saturated = np.zeros(big_n, dtype=bool)
    n_contact = np.zeros(big_n, dtype=np.int64)
    pattern = np.zeros(big_n, dtype=np.int64)
    for i, col in enumerate(cols):
        finite &= np.isfinite(col)
        saturated |= col >= geometry.stroke_mm
        touching = col > contact_threshold_mm
        n_contact += touching
        pattern |= touching.astype(np.int64) << i
    code[~finite] = NAN
    code[finite & saturated] = SATURATED
    code[(code == OK) & (n_contact < 4)] = CONTACT
    x, y, k = (np.asarray(v) for v in (geometry.x_mm, geometry.y_mm, geometry.k_n_per_mm))
    with np.errstate(all="ignore"):
        ok_patterns = pattern[code == OK]
        same = ok_patterns.size > 0 and bool((ok_patterns == ok_patterns[0]).all())
        for pat in ok_patterns[:1] if same else np.unique(ok_patterns):
            rows = np.flatnonzero((pattern == pat) & (code == OK))
            idx = np.flatnonzero((int(pat) >> np.arange(n)) & 1)
            every = rows.size == big_n  # the common case: no fancy indexing needed
            d = [cols[j] if every else cols[j][rows] for j in idx]
            rigid = np.ones(rows.size, dtype=bool)
            for dj in d[1:]:
                rigid &= np.abs(d[0] - dj) <= equal_tol_mm
            if idx.size == 4:
                p = [k[j] * d[pos] - k[idx[0]] * d[0] for pos, j in enumerate(idx[1:], start=1)]
                b = [d[0] - d[pos] for pos in (1, 2, 3)]
                g = geometry_columns(geometry.x_mm, geometry.y_mm, idx.tolist())
                zu, zp, zt, c = solve3(np.sqrt, p[0], p[1], p[2], b[0], b[1], b[2], g)
            else:
                dd = np.column_stack(d)
                mat = np.stack(
                    [
                        np.ones_like(dd),
                        -k[idx] * dd,
                        np.broadcast_to(-x[idx], dd.shape),
                        np.broadcast_to(-y[idx], dd.shape),
                    ],
                    axis=-1,
                )
                scale = np.linalg.norm(mat, axis=1, keepdims=True)
                uu, sv, vt = np.linalg.svd(mat / scale, full_matrices=False)
                z = np.einsum("gji,gj->gi", vt, np.einsum("gmj,gm->gj", uu, dd) / sv) / scale[:, 0]
                zu, zp, zt, c = z[:, 1], z[:, 2], z[:, 3], sv[:, 0] / sv[:, -1]
            c = np.where(np.isfinite(c), c, np.inf)
            u[rows], tp[rows], tt[rows], cond[rows] = zu, zp, zt, c
            code[rows[rigid]] = RIGID
            cond[rows[rigid]] = np.nan
    ok = code == OK
    code[ok & ~(cond <= max_condition)] = ILL
    ok = code == OK
    physical = (u > 0) & np.isfinite(u) & np.isfinite(tp) & np.isfinite(tt)
    code[ok & ~physical] = NONPHYSICAL
    valid = code == OK
    nan = np.full(big_n, np.nan)
    with np.errstate(all="ignore"):
        k_t = np.where(valid, 1.0 / u, nan)
        contact = dx > contact_threshold_mm
        dt = np.where(valid[:, None], np.where(contact, dx * k * u[:, None], 0.0), np.nan)
    return BatchSolution(
        valid,
        code,
        k_t,
        np.where(valid, np.arctan(tp), nan),
        np.where(valid, np.arctan(tt), nan),
        dt,
        np.where(valid | (code == ILL) | (code == NONPHYSICAL), cond, nan),
    )
