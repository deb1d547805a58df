"""The specimen as the arm finds it: touch-off points, a fitted surface, the scan region and whether it fits.

A rig does not know a specimen's surface to a millimetre. Before a raster the scanner touches down at a few
points over the region (a grid, corners included), records the height where each touch-off found the surface,
and fits a smooth surface through them (:func:`fit_surface`: a plane, or a quadratic that follows a dome). The
raster is then planned at the probe's working offset over that surface (``models.raster``'s ``surface``).

The region comes from the specimen: by default its footprint (as someone measured it) less an edge margin
(:func:`region_in_footprint`), or, given only a box to search, the extent of the points of a coarse grid
(:func:`search_points`) where the touch-off found the specimen, less the margin (:func:`region_from_touches`); :func:`check_fits` refuses, before any motion, a region or a specimen height that the
workspace box cannot hold, naming the box and the extent. Units mm, phantom frame (origin at a corner, z up, table
at z = 0). Pure functions; the scanner (nodes/scanner/touchoff.py) supplies the measurements.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "SpecimenDoesNotFit",
    "SurfaceFit",
    "check_fits",
    "contact_onset_z",
    "fit_surface",
    "flat_surface",
    "region_from_touches",
    "region_in_footprint",
    "search_points",
    "touch_points",
]

Region = tuple[float, float, float, float]
Box = tuple[float, float, float, float, float, float]
_LAW_ERROR = 0.05  # contact_onset_z: how far a contact law is taken to be off, relative


class SpecimenDoesNotFit(ValueError):
    """The region or the specimen's height does not fit the workspace box (the message has both)."""


@dataclass(frozen=True)
class SurfaceFit:
    """z(x, y) = c0 + c1 u + c2 v [+ c3 u^2 + c4 u v + c5 v^2], with u, v = x - cx, y - cy (mm)."""

    coeffs: tuple[float, ...]
    centre_mm: tuple[float, float]
    model: Literal["plane", "quadratic"]
    rms_mm: float
    """Root-mean-square residual of the touch-off heights about the fit (0 for an exact fit)."""
    points: int

    def z(self, x_mm: float, y_mm: float) -> float:
        """Surface height (mm) at (x, y)."""
        u, v = x_mm - self.centre_mm[0], y_mm - self.centre_mm[1]
        c = self.coeffs
        z = c[0] + c[1] * u + c[2] * v
        if self.model == "quadratic":
            z += c[3] * u * u + c[4] * u * v + c[5] * v * v
        return float(z)

    def __call__(self, x_mm: float, y_mm: float) -> float:
        return self.z(x_mm, y_mm)

    def top_mm(self, region: Region, step_mm: float = 1.0) -> float:
        """Highest point of the surface over ``region`` (sampled every ``step_mm``, edges included)."""
        x0, y0, x1, y1 = region
        xs = np.linspace(x0, x1, max(2, math.ceil((x1 - x0) / step_mm) + 1))
        ys = np.linspace(y0, y1, max(2, math.ceil((y1 - y0) / step_mm) + 1))
        return max(self.z(float(x), float(y)) for x in xs for y in ys)


def flat_surface(z_mm: float) -> SurfaceFit:
    """A level surface at ``z_mm`` (what a scan assumes when it does not touch off)."""
    return SurfaceFit((float(z_mm), 0.0, 0.0), (0.0, 0.0), "plane", 0.0, 0)


def touch_points(region: Region, grid: int = 3) -> list[tuple[float, float]]:
    """Touch-off points over ``region``: a ``grid`` x ``grid`` lattice corners included (grid >= 2); grid 2 is the
    four corners and the centre. Ordered row by row, boustrophedon, so consecutive points are neighbours."""
    if grid < 2:
        raise ValueError(f"touch_points: grid must be >= 2, got {grid}")
    x0, y0, x1, y1 = region
    xs = np.linspace(x0, x1, grid).tolist()
    ys = np.linspace(y0, y1, grid).tolist()
    pts: list[tuple[float, float]] = []
    for j, y in enumerate(ys):
        row = xs if j % 2 == 0 else xs[::-1]
        pts += [(float(x), float(y)) for x in row]
    if grid == 2:
        pts.insert(2, ((x0 + x1) / 2, (y0 + y1) / 2))
    return pts


def fit_surface(points: Sequence[tuple[float, float, float]],
                model: Literal["auto", "plane", "quadratic"] = "auto") -> SurfaceFit:
    """Least-squares surface through touch-off points (x, y, z) mm. ``auto``: a quadratic when the points span
    two dimensions with at least 3 distinct positions along each axis and 6 points, else a plane. Raises
    ValueError with fewer than 3 points, or when they do not span the region (all on one line)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise ValueError(f"fit_surface: need at least 3 finite touch-off points, got {len(pts)}")
    cx, cy = float(pts[:, 0].mean()), float(pts[:, 1].mean())
    u, v, z = pts[:, 0] - cx, pts[:, 1] - cy, pts[:, 2]
    distinct = min(len(np.unique(np.round(u, 3))), len(np.unique(np.round(v, 3))))
    if model == "auto":
        model = "quadratic" if len(pts) >= 6 and distinct >= 3 else "plane"
    cols = [np.ones_like(u), u, v]
    if model == "quadratic":
        cols += [u * u, u * v, v * v]
    a = np.stack(cols, axis=1)
    if np.linalg.matrix_rank(a) < a.shape[1]:
        raise ValueError(f"fit_surface: the {len(pts)} touch-off points cannot define a {model} surface "
                         "(too few distinct positions along x or y)")
    coeffs, *_ = np.linalg.lstsq(a, z, rcond=None)
    rms = float(np.sqrt(np.mean((a @ coeffs - z) ** 2)))
    return SurfaceFit(tuple(float(c) for c in coeffs), (cx, cy), model, rms, len(pts))


def contact_onset_z(samples: Sequence[tuple[float, float]], powers: Sequence[float], *,
                    noise: float = 0.0, prior: tuple[float, float] | None = None) -> float | None:
    """The height z0 where a contact signal began, from (z, s) samples of its rise as the probe descends.

    The signal is taken as s = (k (z0 - z))^p: for each exponent p in ``powers`` the samples' s^(1/p) is fitted as
    a line in z, and the exponent whose curve best fits the samples gives z0. Each sample's misfit is weighed by
    what it can be off by: 5 % of itself (a law is no better), or the readings' ``noise`` (sigma) where that is more,
    so that the small signals near the onset count as much as the large ones unless noise drowns them. ``prior``
    (mean, sigma) adds ((p - mean) / sigma)^2 to an exponent's misfit: readings must earn a departure from it.

    One exponent is a known law (1: the camera probe's springs); several, an unknown one: a sphere on a thick
    elastic layer rises as 1.5, and on a thin layer over the table it stiffens well past that, so a fixed 1.5 puts
    the surface too low by as much as the layer stiffens.
    None when the samples cannot tell: fewer than 3 (4 with a free exponent), no spread in z, or no rising line.
    """
    pts = [(z, s) for z, s in samples if s > 0.0 and math.isfinite(z) and math.isfinite(s)]
    if len(pts) < (3 if len(powers) == 1 else 4):
        return None
    z = np.array([p[0] for p in pts])
    s = np.array([p[1] for p in pts])
    if float(np.ptp(z)) < 1e-3:
        return None
    best: tuple[float, float] | None = None  # (weighted misfit, z0)
    design = np.column_stack([z, np.ones_like(z)])
    for p in powers:
        (slope, icept), *_ = np.linalg.lstsq(design, s ** (1.0 / p), rcond=None)
        if not slope < 0.0:  # the signal must grow as the probe goes down
            continue
        z0 = -float(icept) / float(slope)
        model = np.clip(float(slope) * (z - z0), 0.0, None) ** p
        err = float(np.sum((model - s) ** 2 / ((_LAW_ERROR * s) ** 2 + noise ** 2)))
        if prior is not None:
            err += ((p - prior[0]) / prior[1]) ** 2
        if best is None or err < best[0]:
            best = (err, z0)
    return None if best is None else best[1]


def region_in_footprint(footprint: Region, margin_mm: float) -> Region:
    """The footprint (x0, y0, x1, y1) less ``margin_mm`` on every side; ValueError when nothing is left."""
    x0, y0, x1, y1 = footprint
    r = (x0 + margin_mm, y0 + margin_mm, x1 - margin_mm, y1 - margin_mm)
    if not (r[0] <= r[2] and r[1] <= r[3]):
        raise ValueError(f"the specimen's footprint x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm is smaller than twice "
                         f"the {margin_mm:g} mm edge margin: nothing left to scan")
    return r


def _box_text(box: Box) -> str:
    return f"x {box[0]:g}..{box[3]:g}, y {box[1]:g}..{box[4]:g}, z {box[2]:g}..{box[5]:g} mm"


def check_fits(region: Region, box: Box, *, top_mm: float | None = None, clearance_mm: float = 0.0,
               what: str = "the scan region") -> None:
    """Raise :class:`SpecimenDoesNotFit` when ``region`` (x0, y0, x1, y1) leaves the workspace ``box`` (xmin,
    ymin, zmin, xmax, ymax, zmax), or when a surface up to ``top_mm`` plus ``clearance_mm`` (the probe's retract
    height above it) does not fit under the box's top. The message names the box, the extent and the overrun."""
    x0, y0, x1, y1 = region
    if not all(math.isfinite(v) for v in region) or x0 > x1 or y0 > y1:
        raise SpecimenDoesNotFit(f"{what} {region} is not a rectangle x0 <= x1, y0 <= y1 (mm)")
    over = []
    for name, lo, hi, blo, bhi in (("x", x0, x1, box[0], box[3]), ("y", y0, y1, box[1], box[4])):
        if lo < blo:
            over.append(f"{name} {lo:g} < {name}_min {blo:g}")
        if hi > bhi:
            over.append(f"{name} {hi:g} > {name}_max {bhi:g}")
    if over:
        raise SpecimenDoesNotFit(f"{what} x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm does not fit the workspace box "
                                 f"({_box_text(box)}): {'; '.join(over)}. Give a workspace_mm that holds it, or a "
                                 "smaller region_mm")
    if top_mm is not None and top_mm + clearance_mm > box[5]:
        raise SpecimenDoesNotFit(f"the specimen's surface up to z {top_mm:.1f} mm plus the {clearance_mm:g} mm retract "
                                 f"clearance ({top_mm + clearance_mm:.1f} mm) is above the workspace box "
                                 f"({_box_text(box)}): z_max {box[5]:g}. Raise workspace_mm's z_max or lower "
                                 "retract_clearance_mm")
    if top_mm is not None and top_mm < box[2]:
        raise SpecimenDoesNotFit(f"the specimen's surface (top z {top_mm:.1f} mm) lies below the workspace box's "
                                 f"floor ({_box_text(box)}): z_min {box[2]:g}")


def search_points(box: Region, step_mm: float) -> list[tuple[float, float]]:
    """A grid over ``box`` (x0, y0, x1, y1), edges included, at most ``step_mm`` apart, row by row boustrophedon: where
    a search touches down to find the specimen (contact or none)."""
    if not (math.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"search_points: step_mm must be finite and > 0, got {step_mm!r}")
    x0, y0, x1, y1 = box
    xs = np.linspace(x0, x1, max(2, math.ceil((x1 - x0) / step_mm) + 1)).tolist()
    ys = np.linspace(y0, y1, max(2, math.ceil((y1 - y0) / step_mm) + 1)).tolist()
    return [(float(x), float(y)) for j, y in enumerate(ys) for x in (xs if j % 2 == 0 else xs[::-1])]


def region_from_touches(touches: Sequence[tuple[float, float, float]], margin_mm: float,
                        searched: Region | None = None) -> Region:
    """The scan region from a search: the extent (x0, y0, x1, y1) of the points where the specimen was found, less
    ``margin_mm``. ValueError naming the ``searched`` box when nothing, or too little to scan, was found."""
    where = (f" in the searched box x {searched[0]:g}..{searched[2]:g}, y {searched[1]:g}..{searched[3]:g} mm"
             if searched is not None else "")
    if not touches:
        raise ValueError(f"the search found no specimen{where}: is it under the box, and thicker than the floor?")
    xs, ys = [t[0] for t in touches], [t[1] for t in touches]
    extent = (min(xs), min(ys), max(xs), max(ys))
    try:
        return region_in_footprint(extent, margin_mm)
    except ValueError:
        raise ValueError(f"the search found the specimen only at x {extent[0]:g}..{extent[2]:g}, y {extent[1]:g}.."
                         f"{extent[3]:g} mm{where}: smaller than twice the {margin_mm:g} mm edge margin (a finer "
                         "search_step_mm, or a smaller edge_margin_mm)") from None
