"""Scoring a scan's outputs against the phantom's truth (pure; used only outside the graph).

The graph never sees the truth: tests, bench scripts, ``tools.scan_report`` and the evaluation runner call
:func:`score_scan` after a run with the phantom, the detected inclusions (``inclusions.json`` records) and the map
grid (``map.npz`` arrays).

Rules (docs/physics.md, "Scoring a scan"):

* **Matching.** A detection may match a true inclusion when its centroid lies within the true footprint widened by
  ``tolerance_mm`` (default: half a map cell), i.e. ``dist <= R_true + tolerance``. Matches are one-to-one and
  minimise the summed centroid distance (Hungarian assignment). A true inclusion with no match is *missed*; a
  detection with no match is a *false positive*.
* **Map inclusion cells.** A cell is called inclusion by the map when its centre lies inside any detected
  inclusion's circle ``(x_mm, y_mm, radius_mm)``; it is truly inclusion when its centre lies inside a true
  inclusion's footprint (``Phantom.inclusion_at``). Only cells whose centre is on the phantom's footprint are
  scored. Sensitivity = TP / (TP + FN), specificity = TN / (TN + FP) over those cells; IoU = TP / (TP + FP + FN);
  the symmetric difference is (FP + FN) cells times the cell area (mm²).
* Per matched inclusion: the centroid error (mm), the radius error (detected − true, mm) and the IoU of the two
  discs (exact circle-circle intersection).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from models.phantom import Phantom

__all__ = ["Detection", "InclusionScore", "MapGrid", "ScanScore", "disc_iou", "redraw_misses", "score_scan"]


@dataclass(frozen=True, slots=True)
class Detection:
    """One detected inclusion as ``inclusions.json`` stores it (mm; contrast = peak / baseline)."""

    x_mm: float
    y_mm: float
    radius_mm: float
    contrast: float = math.nan

    @classmethod
    def from_record(cls, rec: Mapping[str, float], where: str = "detection") -> Detection:
        """From an ``inclusions.json`` record; a missing or non-numeric key is a ValueError naming it."""
        vals = []
        for key in ("x_mm", "y_mm", "radius_mm"):
            v = rec.get(key) if isinstance(rec, Mapping) else None
            if not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"{where}: {key} must be a finite number, got {v!r}")
            vals.append(float(v))
        if vals[2] < 0:
            raise ValueError(f"{where}: radius_mm must be >= 0, got {vals[2]}")
        c = rec.get("contrast", math.nan)
        return cls(vals[0], vals[1], vals[2], float(c) if isinstance(c, int | float) else math.nan)


@dataclass(frozen=True, slots=True)
class MapGrid:
    """The map grid of ``map.npz``: stiffness (ny, nx), cell-centre axes x_mm (nx) and y_mm (ny), count (ny, nx)."""

    stiffness: npt.NDArray[np.float64]
    x_mm: npt.NDArray[np.float64]
    y_mm: npt.NDArray[np.float64]
    count: npt.NDArray[np.int64]

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, npt.ArrayLike]) -> MapGrid:
        """From ``np.load("map.npz")`` or any mapping with those four keys; shapes are checked."""
        try:
            s = np.asarray(arrays["stiffness"], dtype=np.float64)
            x = np.asarray(arrays["x_mm"], dtype=np.float64)
            y = np.asarray(arrays["y_mm"], dtype=np.float64)
            c = np.asarray(arrays["count"], dtype=np.int64)
        except KeyError as exc:
            raise ValueError(f"map grid: missing array {exc.args[0]!r}") from None
        if s.ndim != 2 or s.shape != (y.size, x.size) or c.shape != s.shape:
            raise ValueError(f"map grid: stiffness {s.shape} and count {c.shape} must be (len(y_mm), len(x_mm)) = "
                             f"({y.size}, {x.size})")
        return cls(s, x, y, c)

    @property
    def cell_mm(self) -> float:
        """Cell size (mm) from the axes' spacing (1.0 for a single-cell axis)."""
        steps = [float(np.median(np.diff(a))) for a in (self.x_mm, self.y_mm) if a.size > 1]
        return steps[0] if steps else 1.0


@dataclass(frozen=True, slots=True)
class InclusionScore:
    """One true inclusion: found or missed; for a match, its errors."""

    index: int  # in the phantom's inclusions
    center_mm: tuple[float, float]
    radius_mm: float
    ratio: float  # inclusion / background modulus (or spring constant)
    found: bool
    centroid_error_mm: float = math.nan
    radius_error_mm: float = math.nan  # detected - true
    disc_iou: float = math.nan
    detection: Detection | None = None


@dataclass(frozen=True, slots=True)
class ScanScore:
    """Everything :func:`score_scan` measures; ``summary()`` formats it for a report."""

    inclusions: tuple[InclusionScore, ...]
    false_positives: tuple[Detection, ...]
    true_positive_cells: int
    false_positive_cells: int
    false_negative_cells: int
    true_negative_cells: int
    cell_area_mm2: float

    @property
    def found(self) -> int:
        return sum(s.found for s in self.inclusions)

    @property
    def sensitivity(self) -> float:
        """Fraction of true inclusion cells the map calls inclusion (nan without inclusion cells)."""
        pos = self.true_positive_cells + self.false_negative_cells
        return self.true_positive_cells / pos if pos else math.nan

    @property
    def specificity(self) -> float:
        """Fraction of healthy cells the map calls healthy (nan without healthy cells)."""
        neg = self.true_negative_cells + self.false_positive_cells
        return self.true_negative_cells / neg if neg else math.nan

    @property
    def iou(self) -> float:
        """Intersection over union of the map's and the truth's inclusion cells (nan when both are empty)."""
        union = self.true_positive_cells + self.false_positive_cells + self.false_negative_cells
        return self.true_positive_cells / union if union else math.nan

    @property
    def symmetric_difference_mm2(self) -> float:
        """Area (mm²) called inclusion by exactly one of map and truth."""
        return (self.false_positive_cells + self.false_negative_cells) * self.cell_area_mm2

    def summary(self) -> list[str]:
        """Human-readable lines: one per true inclusion, false positives, the cell statistics."""
        lines = []
        for s in self.inclusions:
            head = f"true #{s.index + 1} r {s.radius_mm:g} mm x{s.ratio:.3g} at ({s.center_mm[0]:g}, {s.center_mm[1]:g})"
            if s.found:
                lines.append(f"{head}: found, centroid error {s.centroid_error_mm:.2f} mm, radius error "
                             f"{s.radius_error_mm:+.2f} mm, disc IoU {s.disc_iou:.2f}")
            else:
                lines.append(f"{head}: MISSED")
        for d in self.false_positives:
            lines.append(f"false positive at ({d.x_mm:.1f}, {d.y_mm:.1f}) mm, radius {d.radius_mm:.1f} mm")
        lines.append(f"cells: sensitivity {self.sensitivity:.2f}, specificity {self.specificity:.3f}, "
                     f"IoU {self.iou:.2f}, symmetric difference {self.symmetric_difference_mm2:.0f} mm²")
        return lines


def disc_iou(c1: tuple[float, float], r1: float, c2: tuple[float, float], r2: float) -> float:
    """Intersection over union of two discs (exact lens area); 0 for disjoint discs, nan for two empty ones."""
    d = math.dist(c1, c2)
    a1, a2 = math.pi * r1 * r1, math.pi * r2 * r2
    if r1 <= 0 and r2 <= 0:
        return math.nan
    if d >= r1 + r2:
        inter = 0.0
    elif d <= abs(r1 - r2):
        inter = math.pi * min(r1, r2) ** 2
    else:
        u = (d * d + r1 * r1 - r2 * r2) / (2 * d * r1)
        v = (d * d + r2 * r2 - r1 * r1) / (2 * d * r2)
        k = (-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)
        inter = r1 * r1 * math.acos(u) + r2 * r2 * math.acos(v) - 0.5 * math.sqrt(max(k, 0.0))
    return inter / (a1 + a2 - inter)


def redraw_misses(found_in: Sequence[int], draws: int) -> float:
    """How many of a method's own detections it would lose if each run were made again with another noise draw:
    the expected count, summed over runs, of inclusions found in a run's draw and missed in another draw picked at
    random among the other ``draws - 1`` of the same phantom. ``found_in``: per inclusion, in how many of the
    ``draws`` draws the method found it.

    The yardstick for "finds every inclusion the raster finds" on the same draw: an inclusion the raster finds in
    ``k`` draws of ``K`` is lost to the raster itself, redrawn, ``k (K - k) / (K - 1)`` times over its ``K`` runs,
    so a second method can only be held to the raster's own redraw losses, not to zero."""
    if draws < 2:
        raise ValueError(f"draws: need at least 2 noise draws to redraw, got {draws}")
    if any(not 0 <= k <= draws for k in found_in):
        raise ValueError(f"found_in: each count must lie in 0..{draws}, got {list(found_in)}")
    return sum(k * (draws - k) for k in found_in) / (draws - 1)


def _match(phantom: Phantom, found: Sequence[Detection], tol: float) -> dict[int, int]:
    """true index -> detection index, one-to-one, minimum total distance among allowed pairs."""
    truth = phantom.inclusions
    if not truth or not found:
        return {}
    dist = np.array([[math.dist(t.center_mm, (f.x_mm, f.y_mm)) for f in found] for t in truth])
    allowed = dist <= np.array([[t.radius_mm + tol] for t in truth])
    big = 1e6 + dist.max()
    rows, cols = linear_sum_assignment(np.where(allowed, dist, big))
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if allowed[r, c]}


def score_scan(
    phantom: Phantom,
    detections: Sequence[Detection | Mapping[str, float]],
    grid: MapGrid | Mapping[str, npt.ArrayLike],
    *,
    tolerance_mm: float | None = None,
) -> ScanScore:
    """Score one scan: per true inclusion found/missed and errors, false positives, cell statistics (module doc)."""
    g = grid if isinstance(grid, MapGrid) else MapGrid.from_arrays(grid)
    found = [d if isinstance(d, Detection) else Detection.from_record(d, f"inclusions[{i}]")
             for i, d in enumerate(detections)]
    cell = g.cell_mm
    tol = 0.5 * cell if tolerance_mm is None else float(tolerance_mm)
    pairs = _match(phantom, found, tol)
    base = phantom.spring_constant_n_per_mm if phantom.is_spring_sample else phantom.youngs_modulus_kpa
    scores = []
    for i, t in enumerate(phantom.inclusions):
        value = t.spring_constant_n_per_mm if phantom.is_spring_sample else t.youngs_modulus_kpa
        ratio = float(value or math.nan) / float(base or math.nan)
        c = (float(t.center_mm[0]), float(t.center_mm[1]))
        if i in pairs:
            d = found[pairs[i]]
            scores.append(InclusionScore(
                i, c, t.radius_mm, ratio, True, centroid_error_mm=math.dist(c, (d.x_mm, d.y_mm)),
                radius_error_mm=d.radius_mm - t.radius_mm,
                disc_iou=disc_iou(c, t.radius_mm, (d.x_mm, d.y_mm), d.radius_mm), detection=d))
        else:
            scores.append(InclusionScore(i, c, t.radius_mm, ratio, False))
    used = set(pairs.values())
    yy, xx = np.meshgrid(g.y_mm, g.x_mm, indexing="ij")
    lx, ly = phantom.size_mm
    on = (xx >= 0) & (xx <= lx) & (yy >= 0) & (yy <= ly)
    truth = np.asarray(phantom.inclusion_at(xx, yy)) >= 0
    called = np.zeros(xx.shape, dtype=bool)
    for d in found:
        called |= (xx - d.x_mm) ** 2 + (yy - d.y_mm) ** 2 <= d.radius_mm**2
    truth, called = truth[on], called[on]
    return ScanScore(
        inclusions=tuple(scores),
        false_positives=tuple(f for j, f in enumerate(found) if j not in used),
        true_positive_cells=int(np.sum(truth & called)),
        false_positive_cells=int(np.sum(~truth & called)),
        false_negative_cells=int(np.sum(truth & ~called)),
        true_negative_cells=int(np.sum(~truth & ~called)),
        cell_area_mm2=cell * cell,
    )
