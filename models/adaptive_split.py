"""Two inclusions joined into one blob: split a detection where its *measured* cells show two maxima with a
measured dip between them.

The map detector (:func:`models.detector.detect`) calls every connected region above its threshold one inclusion.
Its matched filter averages over discs of the inclusion sizes of interest, so the halos of two inclusions 5 mm apart
edge to edge can join into one region, though the planner measured the dip between them. One inclusion gives one maximum: its excess stiffness falls off from its
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

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from models.detector import Detection, DetectorConfig, describe
from models.peaks import peak_parts
from models.stiffness_map import Inclusion, MapSnapshot

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


def split_detections(det: Detection, snap: MapSnapshot, measured: BoolArray, cfg: DetectorConfig, *,
                     prominence_k: float) -> list[Inclusion]:
    """``det``'s inclusions (models.detector.detect on ``snap`` with ``cfg``) with every region whose measured cells
    show two or more maxima standing ``prominence_k`` times the map's relative noise above the level joining them
    (:func:`peak_parts` over :func:`bridge_levels` of the log-residual against the background) replaced by one
    inclusion per part, each measured as the detector measures a region (models.detector.describe); a part under
    two cells leaves its region whole. Most significant first, as the detector's; ``det.inclusions`` itself when
    nothing splits."""
    found = det.inclusions
    if not found or not det.noise_rel > 0:
        return found
    labels, n = ndimage.label(np.nan_to_num(det.significance, nan=-np.inf) > det.threshold_snr, structure=_EIGHT)
    level = bridge_levels(det.residual, measured)
    step = prominence_k * det.noise_rel
    pieces: list[list[BoolArray]] = []
    for k in range(1, n + 1):
        region = labels == k
        cut = peak_parts(level, region, region & measured, step)
        pieces.append(cut if len(cut) > 1 and all(p.sum() >= 2 for p in cut) else [region])
    if all(len(p) == 1 for p in pieces):
        return found
    out = [describe(det, snap, part, cfg, part=len(cut) > 1) for cut in pieces for part in cut]
    return sorted(out, key=lambda i: -i.snr)
