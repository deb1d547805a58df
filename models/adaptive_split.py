"""Two inclusions joined into one blob: split a detection where its *measured* cells show two maxima with a
measured dip between them.

The map detector (:func:`models.stiffness_map.detect_inclusions`) calls every connected region above its threshold
one inclusion. On the raster's map that threshold sits above the dip between two close neighbours often enough; the
adaptive planner's baseline takes its noise scale from the blind cells below their median (smaller: it must not
hide a weak inclusion), and with that threshold the halos of two inclusions 5 mm apart edge to edge can join, though
the planner measured the dip between them. One inclusion gives one maximum: its excess stiffness falls off from its
middle through its halo (the tissue spreads a stiff body's load, it does not ring), so a second maximum inside the
same region that stands above the lowest level joining the two by more than the noise does is a second body.

Evidence is what was measured: the maxima must be measured cells, and the level at which two maxima join is read
from measured cells only. An unmeasured cell of the region (the GP's guess between sweeps) counts as high as the
stiffer of its measured neighbours left, right, above and below (between two sweeps that both crossed a dip it lies
in the dip; next to one that crossed a peak it bridges as high), or as a free bridge with none: a dip only the GP
shows is no evidence, and a region measured too sparsely is never split. Tie-breaks are by cell index,
so the split is deterministic. Our own code (a watershed on the superlevel sets, as in topological persistence).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from models.stiffness_map import Inclusion, MapSnapshot, detect_inclusions, fill_gaps

__all__ = ["bridge_levels", "peak_parts", "split_detections"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
_EIGHT = np.ones((3, 3), dtype=bool)
_CROSS = np.array([[False, True, False], [True, True, True], [False, True, False]])


def bridge_levels(grid: FloatArray, measured: BoolArray) -> FloatArray:
    """The level each cell joins at: its value where measured, else the stiffest of its measured neighbours left,
    right, above and below (inf with none: an unmeasured stretch is no evidence of a dip)."""
    vals = np.where(measured & np.isfinite(grid), grid, -np.inf)
    near = ndimage.maximum_filter(vals, footprint=_CROSS, mode="constant", cval=-np.inf)
    return np.where(measured, vals, np.where(np.isfinite(near), near, np.inf))


def peak_parts(level: FloatArray, region: BoolArray, peaks: BoolArray, prominence: float) -> list[BoolArray]:
    """The region (8-connected) split into one part per maximum that stands ``prominence`` or more above the level
    at which it joins a higher one (persistence of the superlevel sets), only ``peaks`` cells counting as maxima.
    Cells are flooded from the highest level down; a cell touching two or more parts whose maxima both stand
    ``prominence`` above it keeps them apart and joins the highest of them; otherwise the parts it touches merge.
    One part (the region itself) when no second maximum stands out."""
    idx = np.flatnonzero(region)
    if idx.size == 0:
        return []
    lv = level.ravel()
    order = idx[np.lexsort((idx, -lv[idx]))]   # highest first, ties by index
    ny, nx = region.shape
    parent: dict[int, int] = {}
    peak: dict[int, float] = {}   # root -> its highest measured value (-inf: none yet)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    pk = peaks.ravel()
    for c in order:
        c = int(c)
        y, x = divmod(c, nx)
        roots = {root(n) for n in (yy * nx + xx for yy in range(max(0, y - 1), min(ny, y + 2))
                                   for xx in range(max(0, x - 1), min(nx, x + 2))) if n in parent}
        own = float(lv[c]) if pk[c] else -math.inf
        f = float(lv[c])
        ranked = sorted(roots, key=lambda r: (-peak[r], r))
        apart = [r for r in ranked if peak[r] - f >= prominence]
        parent[c] = c
        peak[c] = own
        target = ranked[0] if ranked else c
        keep = set(apart) if len(apart) >= 2 else set()
        for r in ranked:
            if r != target and r not in keep:
                parent[r] = target
                peak[target] = max(peak[target], peak[r])
        if target != c:
            parent[c] = target
            peak[target] = max(peak[target], own)
    labels: dict[int, int] = {}
    out = np.zeros(region.size, dtype=np.int64)
    for c in idx:
        out[c] = labels.setdefault(root(int(c)), len(labels) + 1)
    flat = out.reshape(region.shape)
    return [flat == k for k in range(1, len(labels) + 1)]


def split_detections(snap: MapSnapshot, measured: BoolArray, reference: tuple[float, float] | None,
                     found: list[Inclusion], *, rel_threshold: float, k_mad: float,
                     prominence_k: float) -> list[Inclusion]:
    """``found`` (detect_inclusions on ``snap`` with these thresholds and ``reference``) with every region whose
    measured cells show two or more maxima standing ``prominence_k`` times the baseline's noise scale above the
    level joining them (:func:`peak_parts` over :func:`bridge_levels`) replaced by one inclusion per part, each
    measured exactly as the detector measures a region (it is handed the part alone); a part under the detector's
    two cells leaves its region whole. Most contrasted first, as the detector's; ``found`` itself when nothing
    splits."""
    grid = fill_gaps(np.asarray(snap.stiffness, dtype=np.float64))
    valid = np.isfinite(grid)
    if not found or valid.sum() < 9:
        return found
    base, sigma = reference if reference is not None else (float(np.median(grid[valid])), math.nan)
    if reference is None or not (base > 0 and sigma > 0):
        return found
    threshold = base + max(k_mad * sigma, rel_threshold * base)
    labels, n = ndimage.label(valid & (grid > threshold), structure=_EIGHT)
    level = bridge_levels(grid, measured)
    step = prominence_k * sigma
    pieces: list[list[BoolArray]] = []
    for k in range(1, n + 1):
        region = labels == k
        cut = peak_parts(level, region, region & measured, step)
        pieces.append(cut if len(cut) > 1 and all(p.sum() >= 2 for p in cut) else [region])
    if all(len(p) == 1 for p in pieces):
        return found
    out: list[Inclusion] = []
    for part in (p for cut in pieces for p in cut):   # each region or part alone: measured as the detector does
        alone = MapSnapshot(np.where(part, grid, np.nan), snap.x_mm, snap.y_mm, snap.count, snap.spread,
                            snap.resolution_mm)
        out += detect_inclusions(alone, rel_threshold=rel_threshold, k_mad=k_mad, gap_fill=False, min_valid_cells=1,
                                 reference=reference)
    return sorted(out, key=lambda i: -i.contrast)
