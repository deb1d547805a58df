"""The order the probe visits a batch of chosen points in, and the coarse first pass it starts with.

A palpation's user waits for time, not probes. Between two short sweeps the arm lifts, travels and comes down again,
and that travel, not the sweep, was most of the adaptive planner's path: probes taken in the order the acquisition
ranked them crossed the specimen back and forth. Two pieces cut it:

* **the route** (:func:`order_route`): an open path from where the probe is through every point of a batch, by the
  usual travelling-salesman heuristic, nearest neighbour then 2-opt (reverse a stretch of the route while that
  shortens it). Deterministic: ties go to the lower index, and 2-opt takes the first improving move in a fixed scan.
* **the coarse pass** (:func:`coarse_pass`): the stiffness-blind covering sweeps, all chosen before any is made and
  then visited in one route. Their layout is the staggered lattice of models.adaptive_cover, spaced by the rule of
  :func:`coarse_spacing`: columns twice the smallest inclusion's reach apart (its radius plus how far past its edge
  a sweep senses it, ``reach_mm``), so that one between two columns lies within about that reach of one of them;
  along a column a sweep every twice its length, the next column's half a period along, so that the neighbours'
  sweeps fill the gaps. (The launch's 8 and 12 mm are this rule's values for the 4 mm reach and 6 mm sweeps.) Where the lattice's edges leave an inclusion room to hide, the greedy sweeps that patch them join the batch.
  Knowing the whole pass first also gives the detector a background from every blind cell before any candidate is
  judged, instead of from the first few.

Our own code; nearest neighbour + 2-opt is the textbook heuristic (within a few per cent of the optimum on such
small, nearly planar batches).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from models.adaptive import PlannerConfig, inside, probe_points
from models.adaptive_cover import cover_lattice, fill_cells

__all__ = ["coarse_pass", "coarse_spacing", "order_route", "route_length"]

Point = tuple[float, float]


def route_length(points: Sequence[Point], start: Point | None = None) -> float:
    """Length (mm) of the open path through ``points`` in their order, from ``start`` when given."""
    path = ([start] if start is not None else []) + list(points)
    return sum(math.dist(a, b) for a, b in zip(path, path[1:], strict=False))


def _nearest_neighbour(points: Sequence[Point], start: Point | None) -> list[int]:
    left = list(range(len(points)))
    order: list[int] = []
    if not points:
        return order
    here: Point = start if start is not None else points[0]
    while left:
        i = min(left, key=lambda k: (math.dist(here, points[k]), k))
        left.remove(i)
        order.append(i)
        here = points[i]
    return order


def _two_opt(order: list[int], points: Sequence[Point], start: Point | None) -> list[int]:
    """Reverse stretches of the open route while one shortens it (first improvement, fixed scan: deterministic)."""
    pts = [points[i] for i in order]
    if start is not None:
        pts = [start, *pts]
    idx = ([-1] if start is not None else []) + list(order)
    n = len(pts)
    improved = True
    sweeps = 0
    while improved and sweeps < 50:
        improved = False
        sweeps += 1
        # reverse pts[i..j]; the first point stays put (the start, or the route's fixed first point)
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                a, b = pts[i - 1], pts[i]
                c = pts[j]
                d = pts[j + 1] if j + 1 < n else None
                before = math.dist(a, b) + (math.dist(c, d) if d is not None else 0.0)
                after = math.dist(a, c) + (math.dist(b, d) if d is not None else 0.0)
                if after < before - 1e-9:
                    pts[i:j + 1] = pts[i:j + 1][::-1]
                    idx[i:j + 1] = idx[i:j + 1][::-1]
                    improved = True
    return [k for k in idx if k >= 0]


def order_route(points: Sequence[Point], start: Point | None = None) -> list[Point]:
    """``points`` in the order of a short open route from ``start`` (or from the first point), each visited once:
    nearest neighbour, then 2-opt. Deterministic."""
    pts = [(float(x), float(y)) for x, y in points]
    if len(pts) < 2:
        return pts
    order = _two_opt(_nearest_neighbour(pts, start), pts, start)
    return [pts[i] for i in order]


def coarse_spacing(reach_mm: float, sweep_mm: float) -> tuple[float, float]:
    """The coarse pass's (column spacing, period along a column), mm (module doc): ``2 * reach_mm`` and
    ``2 * sweep_mm``. Between two columns a point is at most half the spacing, ``reach_mm``, from one, and each
    column's gaps are the next column's sweeps; only near the corners of a gap a point lies a little farther (4.5 mm
    for a 4 mm reach and 6 mm sweeps), where the next radius of interest, sensed from farther, is still seen."""
    if not (reach_mm > 0 and sweep_mm > 0):
        raise ValueError(f"coarse_spacing: reach_mm and sweep_mm must be > 0, got {reach_mm}, {sweep_mm}")
    return 2.0 * reach_mm, 2.0 * sweep_mm


def coarse_pass(cfg: PlannerConfig, start: Point | None = None) -> list[Point]:
    """The coarse first pass (module doc): the covering lattice's sweeps (models.adaptive_cover.cover_lattice) and
    the greedy ones that bring the miss probability under the tolerance past its edges, as probe points, in the
    order of :func:`order_route` from ``start``. Empty without a lattice (presses, or ``cover_column_mm`` 0)."""
    lattice = list(cover_lattice(cfg))
    if not lattice:
        return []
    cells = lattice + fill_cells(cfg, lattice)
    px, py = probe_points(None, cfg)
    points = [inside(cfg, float(px[iy, ix]), float(py[iy, ix])) for iy, ix in cells]   # a partial last cell
    if start is None:   # from the lattice corner nearest the region's origin: the scanner's home side
        x0, y0 = cfg.region_mm[:2]
        start = min(points, key=lambda p: (math.dist(p, (x0, y0)), p))
    return order_route(points, start)
