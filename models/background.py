"""The smooth background under a stiffness map (models.detector, step 1): a quadratic surface in x and y fitted to
``log(stiffness)`` by iteratively reweighted least squares with Tukey's biweight, so a dome's slope or an edge's
drift is followed while an inclusion's raised cells do not pull it up."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from models._arrays import FloatArray

__all__ = ["BACKGROUND_DEGREE", "MAD_TO_SIGMA", "biweight", "fit_background", "raised_above_plane"]

BoolArray = npt.NDArray[np.bool_]

MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to σ, for normal noise."""
BACKGROUND_DEGREE = 2
"""Degree of the background surface in x and y (2: a dome, a tilt, a drift towards an edge)."""

_GUARD_MIN_CELLS = 18
"""The guard leaves at least this many cells (three per term of the quadratic) or leaves the cells as they are."""


def fit_background(logs: FloatArray, use: BoolArray, x: FloatArray, y: FloatArray, *,
                    robust_start: bool = False, guard_snr: float = 0.0) -> FloatArray:
    """A quadratic surface fitted to ``logs`` on the ``use`` cells by Tukey-biweight IRLS, evaluated everywhere;
    no slope or curve along an axis the ``use`` cells span less than half the map of (it would be extrapolated
    from nothing), a constant (the median) when too few cells support the surface.

    The IRLS starts from the least-squares fit (every weight one), unless ``robust_start``: then from the biweights
    of the cells' deviations from their median, so a cluster of raised cells is down-weighted before the surface
    can bend to it (the biweight is not convex: from a start that fits them it keeps them). A partial map's fair
    cells need it: a few segments of a sparse lattice over an inclusion are a large share of a few dozen cells, at
    the map's corner, and the least-squares quadratic through them sits at their level (BENCHMARKS.md "Could any
    sense-then-confirm scheme do it?"). A whole map's fit starts from least squares as it always has (its hundreds
    of cells are not moved so, and its detections stay what they were, to the bit).

    ``guard_snr`` > 0 (with ``robust_start``): the cells :func:`raised_above_plane` by that many σ are left out
    first, when enough stay for the surface (models.detector's guard; 0: none)."""
    if guard_snr > 0 and robust_start:
        kept = use & ~raised_above_plane(logs, use, x, y, guard_snr)
        if _GUARD_MIN_CELLS <= int(kept.sum()) < int(use.sum()):
            use = kept
    gy, gx = np.meshgrid(y, x, indexing="ij")
    sx = max(float(np.ptp(x)), 1e-9) / 2
    sy = max(float(np.ptp(y)), 1e-9) / 2
    u, v = (gx - float(np.mean(x))) / sx, (gy - float(np.mean(y))) / sy
    along_x = float(np.ptp(gx[use])) >= sx if use.any() else False
    along_y = float(np.ptp(gy[use])) >= sy if use.any() else False
    terms = [np.ones_like(u)] + [u**i * v**j for d in range(1, BACKGROUND_DEGREE + 1) for i in range(d + 1)
                                 for j in [d - i] if (along_x or i == 0) and (along_y or j == 0)]
    design = np.stack([t[use] for t in terms], axis=1)
    target = logs[use]
    if target.size < 3 * len(terms):
        return np.full(logs.shape, float(np.median(target)) if target.size else math.nan)
    w: FloatArray = np.ones(target.size)
    if robust_start:
        w = biweight(target - float(np.median(target)), w)
    coef, _, _ = _irls(design, target, w)
    return np.asarray(sum(c * t for c, t in zip(coef, terms, strict=True)), dtype=np.float64)


def _irls(design: FloatArray, target: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Tukey-biweight IRLS of ``target`` on the columns of ``design`` from the weights ``w``, eight rounds: (coefficients,
    residuals, their robust scale) of the last round. A scale at rounding (1e-9 of the target's size: a map without
    noise, a synthetic or quantised one) is no noise: biweights scaled by it would all be zero and the next fit a
    surface of 0, so the fit stops there with the surface it has, and the scale returned is that rounding level."""
    tiny = 1e-9 * max(float(np.max(np.abs(target))), 1e-300) if target.size else 1e-300
    coef: FloatArray = np.zeros(design.shape[1])
    r: FloatArray = np.asarray(target, dtype=np.float64)
    s = tiny
    for _ in range(8):
        sw = np.sqrt(w)
        coef = np.asarray(np.linalg.lstsq(design * sw[:, None], target * sw, rcond=None)[0], dtype=np.float64)
        r = np.asarray(target - design @ coef, dtype=np.float64)
        s = MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r))))
        if not s > tiny:
            s = tiny
            break
        t = r / (4.685 * s)
        w = np.asarray(np.where(np.abs(t) < 1, (1 - t**2) ** 2, 0.0), dtype=np.float64)
    return coef, r, s


def biweight(r: FloatArray, otherwise: FloatArray) -> FloatArray:
    """Tukey's biweights (c = 4.685) of residuals ``r`` about zero, in units of their robust scale (1.4826 median
    absolute value); ``otherwise`` when that scale is zero."""
    s = MAD_TO_SIGMA * float(np.median(np.abs(r)))
    if not s > 0:
        return otherwise
    t = r / (4.685 * s)
    return np.asarray(np.where(np.abs(t) < 1, (1 - t**2) ** 2, 0.0), dtype=np.float64)


def raised_above_plane(logs: FloatArray, use: BoolArray, x: FloatArray, y: FloatArray, k: float) -> BoolArray:
    """The ``use`` cells of ``logs`` lying more than ``k`` robust σ above a plane fitted to them (Tukey-biweight IRLS
    from the median's biweights); none when fewer than :data:`_GUARD_MIN_CELLS` are given.

    Why a plane: a quadratic's corner terms rest on a few cells, and where a third of a sparse lattice's cells lie
    on inclusions near the map's corners the quadratic bends up to them even from a robust start, and the noise
    scale of what is left grows four- to five-fold (spent seed 15005: 0.098 where a blank map's is 0.03). A plane
    cannot bend so; what stands far above it is the first suspect for an inclusion, not for background."""
    out = np.zeros(use.shape, dtype=bool)
    if int(use.sum()) < _GUARD_MIN_CELLS:
        return out
    gy, gx = np.meshgrid(y, x, indexing="ij")
    design = np.stack([np.ones(int(use.sum())), gx[use], gy[use]], axis=1)
    target = logs[use]
    _, r, s = _irls(design, target, biweight(target - float(np.median(target)), np.ones(target.size)))
    out[use] = r > k * s
    return out
