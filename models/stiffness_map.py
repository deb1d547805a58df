"""Stiffness map building and inclusion detection (issue 8).

:class:`StiffnessGrid` bins stiffness samples ``(x_mm, y_mm, value)`` (phantom frame; value in
whatever unit the estimator publishes, e.g. kPa or N/mm) into square cells and reports, per
cell, the **median** of its samples (robust to the odd outlier a probe produces at an edge or
on lift-off), the sample count and the spread ``1.4826 * MAD`` (a robust standard deviation).
Cells with fewer than ``min_count`` samples are NaN.

:func:`models.detector.detect` finds the inclusions on it (one detector for every map);
:func:`to_inclusions_json` turns them into the ``inclusions.json`` records of DESIGN.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "Inclusion",
    "background",
    "MapSnapshot",
    "StiffnessGrid",
    "fill_gaps",
    "nanmedian_stack",
    "to_inclusions_json",
]

_MAD_TO_SIGMA = 1.4826  # MAD of a normal distribution is 0.6745 sigma


@dataclass(frozen=True, slots=True)
class MapSnapshot:
    """The grid at one moment; arrays are read-only copies, indexed [iy, ix]."""

    stiffness: FloatArray  # (ny, nx) per-cell median; NaN where count < min_count
    x_mm: FloatArray  # (nx,) cell centres
    y_mm: FloatArray  # (ny,) cell centres
    count: IntArray  # (ny, nx) samples per cell
    spread: FloatArray  # (ny, nx) 1.4826 * MAD per cell; NaN where count < min_count
    resolution_mm: float


class StiffnessGrid:
    """Accumulates stiffness samples into a regular grid over ``[x0, x1] x [y0, y1]`` (mm).

    Cells are ``resolution_mm`` squares starting at (x0, y0); the last row/column may reach
    past x1/y1 when the extent is not a multiple of the resolution. Samples outside the
    rectangle or with a non-finite coordinate or value are dropped and counted in
    :attr:`dropped`. All samples are kept (16 bytes each: a 10-minute scan at 1 kHz is about
    10 MB) so that medians stay exact; :meth:`snapshot` re-sorts only the cells that changed since the last one.
    """

    def __init__(
        self,
        x0: float,
        y0: float,
        x1: float,
        y1: float,
        resolution_mm: float,
        *,
        min_count: int = 3,
    ) -> None:
        if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or not (x0 < x1 and y0 < y1):
            raise ValueError(
                f"StiffnessGrid: need finite x0 < x1 and y0 < y1, got ({x0}, {y0}, {x1}, {y1})"
            )
        if not (math.isfinite(resolution_mm) and resolution_mm > 0):
            raise ValueError(f"StiffnessGrid: resolution_mm must be > 0, got {resolution_mm}")
        if min_count < 1:
            raise ValueError(f"StiffnessGrid: min_count must be >= 1, got {min_count}")
        self.x0, self.y0, self.x1, self.y1 = float(x0), float(y0), float(x1), float(y1)
        self.resolution_mm = float(resolution_mm)
        self.min_count = int(min_count)
        self.nx = max(1, math.ceil((x1 - x0) / resolution_mm - 1e-9))
        self.ny = max(1, math.ceil((y1 - y0) / resolution_mm - 1e-9))
        self.dropped = 0
        n_cells = self.nx * self.ny
        self._sorted: dict[int, FloatArray] = {}
        """Each cell's samples so far, ascending, as of the last :meth:`snapshot`."""
        self._new_cells: list[IntArray] = []
        self._new_values: list[FloatArray] = []
        """Samples added since the last snapshot (cell index, value)."""
        self._count = np.zeros(n_cells, dtype=np.int64)
        self._median = np.full(n_cells, np.nan)
        self._spread = np.full(n_cells, np.nan)
        """Per cell as of the last snapshot (NaN: no sample); a snapshot recomputes only the cells that changed."""
        self._cached: MapSnapshot | None = None

    def __len__(self) -> int:
        """Number of samples accepted so far."""
        return int(self._count.sum()) + sum(len(c) for c in self._new_cells)

    def add(self, x_mm: npt.ArrayLike, y_mm: npt.ArrayLike, value: npt.ArrayLike) -> int:
        """Add one sample or arrays of samples (broadcast together); returns how many landed."""
        x, y, v = (np.ravel(a) for a in np.broadcast_arrays(
            np.asarray(x_mm, dtype=np.float64), np.asarray(y_mm, dtype=np.float64),
            np.asarray(value, dtype=np.float64)))  # fmt: skip
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(v)
        ok &= (x >= self.x0) & (x <= self.x1) & (y >= self.y0) & (y <= self.y1)
        self.dropped += int(ok.size - ok.sum())
        if not ok.any():
            return 0
        r = self.resolution_mm
        ix = np.minimum(((x[ok] - self.x0) / r).astype(np.int64), self.nx - 1)
        iy = np.minimum(((y[ok] - self.y0) / r).astype(np.int64), self.ny - 1)
        self._new_cells.append(iy * self.nx + ix)
        self._new_values.append(v[ok].copy())
        self._cached = None
        return int(ok.sum())

    def snapshot(self) -> MapSnapshot:
        """Per-cell median, count and spread of everything added so far.

        Only the cells that received samples since the last snapshot are recomputed (a scan's map is published
        every second while a few of its hundreds of cells change: issue 40); each is the same arithmetic, to the
        bit, as sorting every sample by cell and value at once (tests/test_models_stiffness_map.py)."""
        if self._cached is not None:
            return self._cached
        if self._new_cells:
            self._update(np.concatenate(self._new_cells), np.concatenate(self._new_values))
            self._new_cells, self._new_values = [], []
        median, spread = self._median.copy(), self._spread.copy()
        thin = self._count < self.min_count
        median[thin] = np.nan
        spread[thin] = np.nan
        r = self.resolution_mm
        snap = MapSnapshot(
            stiffness=median.reshape(self.ny, self.nx),
            x_mm=self.x0 + (np.arange(self.nx, dtype=np.float64) + 0.5) * r,
            y_mm=self.y0 + (np.arange(self.ny, dtype=np.float64) + 0.5) * r,
            count=self._count.copy().reshape(self.ny, self.nx),
            spread=spread.reshape(self.ny, self.nx),
            resolution_mm=r,
        )
        for a in (snap.stiffness, snap.x_mm, snap.y_mm, snap.count, snap.spread):
            a.setflags(write=False)
        self._cached = snap
        return snap

    def _update(self, cells: IntArray, values: FloatArray) -> None:
        """Merge new samples into their cells and recompute those cells' median and spread."""
        order = np.argsort(cells, kind="stable")
        cells, values = cells[order], values[order]
        starts = np.flatnonzero(np.r_[True, cells[1:] != cells[:-1]])
        for cell, part in zip(cells[starts].tolist(), np.split(values, starts[1:]), strict=True):
            old = self._sorted.get(cell)
            ordered = np.sort(part if old is None else np.concatenate((old, part)))
            self._sorted[cell] = ordered
            n = ordered.size
            lo, hi = (n - 1) // 2, n // 2
            median = 0.5 * (ordered[lo] + ordered[hi])
            deviation = np.sort(np.abs(ordered - median))
            self._count[cell] = n
            self._median[cell] = median
            self._spread[cell] = _MAD_TO_SIGMA * (0.5 * (deviation[lo] + deviation[hi]))

def _neighbourhood(grid: FloatArray) -> FloatArray:
    """(9, ny, nx) stack of each cell's 3x3 neighbourhood (NaN outside the grid)."""
    padded = np.pad(grid, 1, constant_values=np.nan)
    ny, nx = grid.shape
    return np.stack([padded[dy : dy + ny, dx : dx + nx] for dy in range(3) for dx in range(3)])


def nanmedian_stack(stack: FloatArray) -> FloatArray:
    """``np.nanmedian(stack, axis=0)`` to the bit (the middle value, or the mean of the middle two, of each
    column's non-NaN values; NaN for a column of NaN, without a warning), by one sort: numpy's own takes its
    masked-array path for fewer than 600 rows, ~1 ms for a map's 3 x 3 neighbourhoods, which the detector asks
    for at every map published (issue 40)."""
    ordered = np.sort(stack, axis=0)  # NaN last
    n = stack.shape[0] - np.isnan(stack).sum(axis=0)
    lo = np.take_along_axis(ordered, np.maximum((n - 1) // 2, 0)[None], axis=0)[0]
    hi = np.take_along_axis(ordered, (n // 2)[None], axis=0)[0]
    out: FloatArray = (lo + hi) / 2  # a column of NaN alone: its first row, NaN
    return out


def fill_gaps(stiffness: FloatArray, min_neighbors: int = 4) -> FloatArray:
    """Fill each NaN cell having at least ``min_neighbors`` valid cells among its 8
    neighbours with their median (one pass, filled cells do not feed each other). A missed
    raster line (one empty row/column: 6 valid neighbours) is bridged; wider holes and the
    unscanned outside stay NaN. Returns a new array."""
    grid = np.asarray(stiffness, dtype=np.float64)
    stack = _neighbourhood(grid)
    n_valid = np.isfinite(stack).sum(axis=0)  # the centre is NaN where we fill
    out = grid.copy()
    holes = np.isnan(grid) & (n_valid >= min_neighbors)
    out[holes] = nanmedian_stack(stack)[holes]
    return out


def spacing_warning(spacing_mm: float, resolution_mm: float) -> str:
    """Why raster lines ``spacing_mm`` apart leave holes in a map of ``resolution_mm`` cells, and what to use; ''
    when they do not. Between two lines lie about ``spacing / resolution - 1`` rows of cells no sample falls in;
    :func:`fill_gaps` bridges one such row, so lines more than two cells apart leave an empty band across every
    inclusion they cross, which then reads as two (6 mm lines on 2 mm cells split each tumour of the air-float
    phantom in two)."""
    if not (spacing_mm > 0 and resolution_mm > 0) or spacing_mm <= 2 * resolution_mm + 1e-9:
        return ""
    empty = math.ceil(spacing_mm / resolution_mm - 1e-9) - 1
    return (f"line spacing {spacing_mm:g} mm leaves {empty} empty rows of {resolution_mm:g} mm cells between raster "
            f"lines; the map bridges only one, so an inclusion crossing the gap can read as two: use spacing_mm <= "
            f"{2 * resolution_mm:g} (twice resolution_mm) or resolution_mm >= {spacing_mm / 2:g} (half the spacing)")


def background(stiffness: npt.ArrayLike) -> tuple[float, float]:
    """Whole-map statistics: (median, 1.4826 * MAD) over the finite cells, in the map's unit; (nan, nan) for a
    map without data. The detector does not use them (inclusions would count as background): models.detector."""
    values = np.asarray(stiffness, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return math.nan, math.nan
    base = float(np.median(values))
    return base, _MAD_TO_SIGMA * float(np.median(np.abs(values - base)))


@dataclass(frozen=True, slots=True)
class Inclusion:
    """A region stiffer than the background: excess-weighted centroid (mm), equivalent radius
    sqrt(area/pi) (mm), contrast = peak / local background, peak value, area (mm^2), cell count; the detector's
    significance (``snr``: σ of the filtered noise) and the per-map false-alarm probability of a peak that high
    (``false_alarm``: the chance a map without inclusions shows one), NaN when not known."""

    x_mm: float
    y_mm: float
    radius_mm: float
    contrast: float
    peak: float
    area_mm2: float
    cells: int
    snr: float = math.nan
    false_alarm: float = math.nan


def to_inclusions_json(inclusions: Sequence[Inclusion]) -> list[dict[str, float]]:
    """``inclusions.json`` records per DESIGN.md: ``{x_mm, y_mm, radius_mm, contrast}``, plus the detector's ``snr``
    and per-map ``false_alarm`` probability where known (a reader of the four keys is unaffected)."""
    out = []
    for i in inclusions:
        rec = {"x_mm": i.x_mm, "y_mm": i.y_mm, "radius_mm": i.radius_mm, "contrast": i.contrast}
        if math.isfinite(i.snr):
            rec |= {"snr": i.snr, "false_alarm": i.false_alarm}
        out.append(rec)
    return out
