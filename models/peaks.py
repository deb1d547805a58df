"""Cutting a region of a map into one part per maximum that stands out (persistence of the superlevel sets): shared
by the map detector (models.detector: two inclusions whose filtered halos join) and the adaptive planner's split on
its measured cells (models.adaptive_split). Our own code (a watershed on the superlevel sets, as in topological
persistence); tie-breaks are by cell index, so a cut is deterministic."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

__all__ = ["joined_across", "peak_parts"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


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


def joined_across(labels: npt.NDArray[np.int_], keep: list[int], blind: BoolArray, gap: int,
                   near: Callable[[int, int], bool]) -> list[list[int]]:
    """The regions ``keep`` of ``labels`` in groups, in label order: two regions are one group when a path of at most
    ``gap`` ``blind`` cells (8-connected) links them and ``near`` says they may be one, or a chain of such links. A
    search from every region through the blind cells around it, each reached cell owned by the region that reached
    it first, as far as ``gap``; wherever two owners' cells (or a region's own) touch within ``gap`` blind cells in
    all, their regions join (models.detector: the pieces of one inclusion on a partial map)."""
    parent = {k: k for k in keep}

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    if gap > 0 and len(keep) > 1 and blind.any():
        ny, nx = labels.shape
        owner = np.where(np.isin(labels, keep), labels, 0)
        dist = np.where(owner > 0, 0, -1)
        queue = deque((int(y), int(x)) for y, x in np.argwhere(owner > 0))
        while queue:
            y, x = queue.popleft()
            for yy in range(max(0, y - 1), min(ny, y + 2)):
                for xx in range(max(0, x - 1), min(nx, x + 2)):
                    if owner[yy, xx] > 0 and owner[yy, xx] != owner[y, x]:
                        if dist[y, x] + dist[yy, xx] <= gap and near(int(owner[y, x]), int(owner[yy, xx])):
                            a, b = root(int(owner[y, x])), root(int(owner[yy, xx]))
                            parent[max(a, b)] = min(a, b)
                    elif owner[yy, xx] == 0 and blind[yy, xx] and dist[y, x] < gap:
                        owner[yy, xx], dist[yy, xx] = owner[y, x], dist[y, x] + 1
                        queue.append((yy, xx))
    groups: dict[int, list[int]] = {}
    for k in keep:
        groups.setdefault(root(k), []).append(k)
    return sorted(groups.values())
