"""Where an inclusion could still hide, and the sweeps that leave it no room: the covering half of the detection rule.

An inclusion of radius ``r`` whose centre lies within ``r`` plus the sensing reach of a measured cell raised that
cell (models.adaptive_detect's module doc); one farther from every measured cell could lie there unseen. With its
centre uniform over the region and its radius uniform over the span of interest, the probability that it hides is
the fraction of the region farther than its reach from every measured cell, averaged over the radii
(:func:`miss_probability`). The planner stops covering when that is below ``PlannerConfig.miss_probability``.

*Which* sweeps bring it there is a covering problem. Choosing one sweep at a time, the one that reveals the most
hidden area (:func:`coverage_gain`, a greedy set cover), ends with sweeps half a reach apart in places and lone
sweeps patching the corners. A *staggered lattice* covers the plane with less overlap: columns ``cover_column_mm``
apart, along each a sweep every ``cover_period_mm``, the next column's sweeps half a period along, so the gap between
two sweeps of one column lies beside a sweep of the next (a brick wall). Its columns and period were chosen on the
tuning seeds' 40 regions by this criterion alone, the sweeps it takes to bring the miss probability under the
tolerance on tissue with nothing in it, which knows nothing of stiffness: at 1 % (the default), 8 mm columns and a
12 mm period take 976 sweeps where the greedy cover takes 1 142 (15 % fewer; a 10 or 14 mm period 1 031 and 1 009,
6 mm columns 1 056 or more, 10 mm 1 144); at 2 %, 8 and 14 mm take 875 against 1 018. Its phase is chosen for each
region (:func:`cover_lattice`: the one needing the fewest sweeps, its own and the greedy ones that patch its edges).
The planner takes lattice sweeps first (those that still reveal something, the most first) and the greedy choice only
once none does; its seed grid is snapped onto the lattice (:func:`seed_design`) so that no seed sweep is wasted
beside one. The guarantee is unchanged: the planner still stops only when the miss probability is below the
tolerance, whatever the lattice left. Our own code.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from models.adaptive import PlannerConfig, footprint_cells, initial_design, probe_points

__all__ = ["cover_cost", "cover_lattice", "coverage_gain", "distance_to_measured", "fill_cells", "hidden",
           "hidden_fractions", "lattice_cells", "miss_probability", "seed_design", "sweep_stencil", "valid_rows"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def distance_to_measured(observed: BoolArray, resolution_mm: float) -> FloatArray:
    """Distance (mm) from every cell centre to the nearest measured cell's centre (inf with none measured)."""
    obs = np.asarray(observed, dtype=bool)
    if not obs.any():
        return np.full(obs.shape, np.inf)
    return np.asarray(ndimage.distance_transform_edt(~obs), dtype=np.float64) * resolution_mm


def hidden(observed: BoolArray, resolution_mm: float, reach_mm: float) -> BoolArray:
    """Cells where the centre of an inclusion of the smallest radius of interest could lie unseen: farther than
    ``reach_mm`` from every measured cell."""
    return np.asarray(distance_to_measured(observed, resolution_mm) > reach_mm, dtype=bool)


def _reaches(reach_mm: float | Sequence[float]) -> list[float]:
    return [float(reach_mm)] if isinstance(reach_mm, int | float) else [float(r) for r in reach_mm]


def hidden_fractions(observed: BoolArray, resolution_mm: float, reach_mm: float | Sequence[float]) -> list[float]:
    """For each of ``reach_mm``, the fraction of the region's cells that are :func:`hidden` at that reach."""
    d = distance_to_measured(observed, resolution_mm)
    return [np.count_nonzero(d > r) / max(1, d.size) for r in _reaches(reach_mm)]


def miss_probability(observed: BoolArray, resolution_mm: float, reach_mm: float | Sequence[float]) -> float:
    """The probability that an inclusion of interest, its centre uniform over the region, lies where no measurement
    has sensed it: the fraction of :func:`hidden` cells, averaged over ``reach_mm`` when several (one per radius of
    interest, equally likely: PlannerConfig.reaches)."""
    return float(np.mean(hidden_fractions(observed, resolution_mm, reach_mm)))


def sweep_stencil(footprint: int, resolution_mm: float, reach_mm: float) -> BoolArray:
    """The cells (relative to the sweep's centre cell, odd-sized array) within ``reach_mm`` of a sweep that measures
    ``footprint`` consecutive cells along y (rows): what one sweep would no longer leave hidden."""
    rx = math.floor(reach_mm / resolution_mm + 1e-9)
    lo = footprint // 2
    hi = footprint - 1 - lo
    ry = rx + max(lo, hi)
    yy, xx = np.mgrid[-ry:ry + 1, -rx:rx + 1].astype(np.float64)
    # distance from each cell to the nearest cell of the sweep's segment (rows -lo..hi of column 0)
    dy = np.where(yy < -lo, yy + lo, np.where(yy > hi, yy - hi, 0.0))
    return np.asarray(np.hypot(xx, dy) * resolution_mm <= reach_mm + 1e-9, dtype=bool)


def coverage_gain(observed: BoolArray, resolution_mm: float, reach_mm: float | Sequence[float],
                  footprint: int) -> FloatArray:
    """For every sweep centre cell, how many hidden cells (:func:`hidden`) that sweep would reveal (summed over the
    reaches when several: the drop of :func:`miss_probability` it makes, times the cells and reaches)."""
    gain = np.zeros(np.shape(observed), dtype=np.float64)
    dist = distance_to_measured(observed, resolution_mm)
    # a reach given n times (a radius and an offset summing alike) weighs n: one correlation for it
    for r, n in Counter(_reaches(reach_mm)).items():
        h = (dist > r).astype(np.float64)
        st = sweep_stencil(footprint, resolution_mm, r).astype(np.float64)
        # the stencil is symmetric about its centre column; along y an even footprint is centred as in
        # models.adaptive.footprint_score (rows j - lo .. j - lo + k - 1), which the stencil's asymmetric rows encode
        gain += n * ndimage.correlate(h, st, mode="constant", cval=0.0)
    return gain


def valid_rows(ny: int, footprint: int) -> tuple[int, int]:
    """The first and last row a sweep of ``footprint`` cells may be centred on and stay inside ``ny`` rows (as
    models.adaptive.footprint_score: rows j - lo .. j - lo + k - 1); last < first when none may."""
    lo = footprint // 2
    return lo, ny - 1 - (footprint - 1 - lo)


def _sweep_cells(cells: Sequence[tuple[int, int]], shape: tuple[int, int], footprint: int) -> BoolArray:
    """The cells swept by sweeps centred on ``cells`` ((row, column) pairs)."""
    swept = np.zeros(shape, dtype=bool)
    lo = footprint // 2
    for iy, ix in cells:
        swept[max(0, iy - lo):iy - lo + footprint, ix] = True
    return swept


def lattice_cells(shape: tuple[int, int], footprint: int, column: int, period: int, c0: int,
                  r0: int) -> list[tuple[int, int]]:
    """The centre cells (row, column) of a staggered lattice of sweeps over a grid of ``shape``: columns ``c0``,
    ``c0 + column``, ...; along column k a sweep centred every ``period`` rows from ``r0``, half a period further
    on odd columns. A sweep that would stick out of the grid but still crosses it is moved inward to the nearest
    row it may be centred on (:func:`valid_rows`); serpentine order (up one column, down the next)."""
    ny, nx = shape
    first, last = valid_rows(ny, footprint)
    if last < first or column < 1 or period < 1:
        return []
    lo = footprint // 2
    out: list[tuple[int, int]] = []
    for k, ix in enumerate(range(c0, nx, column)):
        start = r0 + (period // 2 if k % 2 else 0)
        start -= period * math.ceil((start + footprint) / period)   # back to before the grid's first row
        rows: list[int] = []
        for iy in range(start, ny + period, period):
            if iy - lo + footprint - 1 < 0 or iy - lo > ny - 1:   # crosses no row of the grid
                continue
            row = min(max(iy, first), last)
            if row not in rows:
                rows.append(row)
        out += [(iy, ix) for iy in (rows if k % 2 == 0 else rows[::-1])]
    return out


def _fill(covered: BoolArray, cfg: PlannerConfig, limit: int) -> list[tuple[int, int]] | None:
    """The greedy sweeps (:func:`coverage_gain`, ties to the first cell), centre cells, that bring the miss
    probability of ``covered`` below the tolerance; None when ``limit`` of them do not."""
    cov = covered.copy()
    k = footprint_cells(cfg)
    first, last = valid_rows(cov.shape[0], k)
    reaches = cfg.reaches()
    cells: list[tuple[int, int]] = []
    while miss_probability(cov, cfg.resolution_mm, reaches) >= cfg.miss_probability:
        if len(cells) >= limit:
            return None
        gain = coverage_gain(cov, cfg.resolution_mm, reaches, k)
        gain[:first] = 0.0
        gain[last + 1:] = 0.0
        iy, ix = np.unravel_index(int(np.argmax(gain)), gain.shape)
        if gain[iy, ix] <= 0:
            return None
        cells.append((int(iy), int(ix)))
        cov |= _sweep_cells([cells[-1]], cov.shape, k)
    return cells


def _fill_count(covered: BoolArray, cfg: PlannerConfig, limit: int) -> int:
    """How many greedy sweeps (:func:`_fill`) bring the miss probability of ``covered`` below the tolerance (at
    most ``limit``: then ``limit``)."""
    cells = _fill(covered, cfg, limit)
    return limit if cells is None else len(cells)


def fill_cells(cfg: PlannerConfig, cells: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
    """The greedy sweeps (centre cells) that, added to the sweeps centred on ``cells``, bring the miss probability
    of ``cfg``'s region below the tolerance, within the probe budget less ``cells`` (as many as that allows)."""
    xs, ys = cfg.grid()
    covered = _sweep_cells(cells, (len(ys), len(xs)), footprint_cells(cfg))
    limit = max(0, cfg.max_probes - len(cells))
    out = _fill(covered, cfg, limit)
    if out is None:   # the budget first: as many as it allows, the most revealing first
        out = []
        k = footprint_cells(cfg)
        first, last = valid_rows(covered.shape[0], k)
        while len(out) < limit:
            gain = coverage_gain(covered, cfg.resolution_mm, cfg.reaches(), k)
            gain[:first] = 0.0
            gain[last + 1:] = 0.0
            iy, ix = np.unravel_index(int(np.argmax(gain)), gain.shape)
            if gain[iy, ix] <= 0:
                break
            out.append((int(iy), int(ix)))
            covered |= _sweep_cells([out[-1]], covered.shape, k)
    return out


def cover_cost(cfg: PlannerConfig, cells: Sequence[tuple[int, int]], limit: int | None = None) -> int:
    """How many sweeps covering ``cfg``'s region takes from the lattice ``cells``: theirs, and the greedy ones
    (:func:`coverage_gain`, ties to the first cell) that bring the miss probability below the tolerance past its
    edges (counted up to ``limit``, default the probe budget: then ``limit``)."""
    xs, ys = cfg.grid()
    k = footprint_cells(cfg)
    covered = _sweep_cells(cells, (len(ys), len(xs)), k)
    cap = cfg.max_probes if limit is None else limit
    return min(cap, len(cells) + _fill_count(covered, cfg, max(0, cap - len(cells))))


@lru_cache(maxsize=64)
def cover_lattice(cfg: PlannerConfig) -> tuple[tuple[int, int], ...]:
    """The lattice of covering sweeps for ``cfg``'s region (centre cells, row and column, serpentine order): the
    phase (first column, first row) needing the fewest sweeps in all, its own and the greedy ones that bring the
    miss probability below the tolerance past its edges (ties: the first phase). Empty when the lattice is off
    (``cover_column_mm`` 0), for presses (no sweep), or with no row a sweep fits in. Deterministic; computed once
    per configuration (a few hundred ms)."""
    if cfg.cover_column_mm <= 0 or cfg.sweep_mm <= 0:
        return ()
    xs, ys = cfg.grid()
    shape = (len(ys), len(xs))
    k = footprint_cells(cfg)
    column = max(1, round(cfg.cover_column_mm / cfg.resolution_mm))
    period = max(k, round(cfg.cover_period_mm / cfg.resolution_mm))
    best: tuple[int, list[tuple[int, int]]] | None = None
    for c0 in range(min(column, shape[1])):
        for r0 in range(period):
            cells = lattice_cells(shape, k, column, period, c0, r0)
            if not cells or (best is not None and len(cells) >= best[0]):
                continue
            cost = cover_cost(cfg, cells, best[0] if best else None)
            if best is None or cost < best[0]:
                best = (cost, cells)
    return tuple(best[1]) if best else ()


def seed_design(cfg: PlannerConfig) -> list[tuple[float, float]]:
    """The first, stiffness-blind probes: the seed grid (models.adaptive.initial_design), each point moved to the
    nearest sweep of the covering lattice (:func:`cover_lattice`; ties: the lattice's first), repeats dropped, so
    that the seed is part of the covering and not beside it. Without a lattice, the seed grid."""
    seeds = initial_design(cfg)
    lattice = cover_lattice(cfg)
    if not lattice:
        return seeds
    px, py = probe_points(None, cfg)
    points = [(float(px[iy, ix]), float(py[iy, ix])) for iy, ix in lattice]
    out: list[tuple[float, float]] = []
    for x, y in seeds:
        p = min(points, key=lambda q: (q[0] - x) ** 2 + (q[1] - y) ** 2)
        if p not in out:
            out.append(p)
    return out
