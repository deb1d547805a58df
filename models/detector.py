"""The inclusion detector every map goes through (issue 37): a matched filter against a robust local background,
with a threshold set by a false-alarm rate per map measured on blank specimens.

A cell reading far above all its neighbours (:attr:`DetectorConfig.spike_ratio`) is dropped first: no tissue under
the probe's footprint reads so, a probe half off the specimen's edge can. A map's noise is multiplicative (eq. 7 turns
a thickness error into a relative stiffness error; an inclusion multiplies the local stiffness), so the detector
works on ``log(stiffness)``:

1. **Background.** A smooth surface (a quadratic in x and y, :data:`BACKGROUND_DEGREE`: models.background) fitted
   by iteratively reweighted least squares (Tukey's biweight) to the cells that are *not candidates*, so a dome's
   slope or an edge's drift is followed while an inclusion's cells do not pull the baseline up (on a partial map,
   the fit starts from the median's biweights, so a few fair cells over an inclusion cannot hold the surface up, and
   is tried again without the cells far above a plane: :attr:`DetectorConfig.guard_noise_ratio`). The residual is the
   log-contrast.
2. **Matched filter.** The residual summed over a disc of each radius of interest (:attr:`DetectorConfig.radii_mm`:
   the sizes of inclusions the scan should find), over the valid cells only, divided by the square root of how many
   valid cells the disc holds, less that quantity's median and in units of its robust scale (1.4826 MAD) over the
   non-candidate cells: the output is in σ units of the *filtered* noise (which is spatially correlated), and a disc
   over the map's edge, holding fewer cells, is no more significant than one inside it.
3. **Candidates.** Cells whose significance at any scale exceeds :attr:`DetectorConfig.candidate_snr` and whose own
   residual exceeds a cell's noise are masked out and steps 1-2 repeated (``iterations`` times): the background and
   the noise scale come from the rest of the map.
4. **Threshold.** The largest significance on a map with no inclusion follows a Gumbel law (the maximum of many
   weakly dependent cells); its location grows with the map's area as ``scale * ln(area / reference area)``.
   :data:`GUMBEL_LOC`, :data:`GUMBEL_SCALE` and :data:`REFERENCE_AREA_MM2` were fitted by
   ``bench/detector_calibration.py`` on blank specimens (a flat 3 mm sheet and the demo's dome without tumours,
   twenty noise draws each; BENCHMARKS.md "The detector's false-alarm rate"), the camera probe's
   (``CAMERA_*``) on its own blank scans: each probe's maps are detected with their own law
   (:data:`FALSE_ALARM_LAWS`, :func:`false_alarm_law`), an adaptive planner's partial maps with theirs
   (:data:`PARTIAL_MAP_LAWS`); the laws live in models.false_alarm. The threshold is the significance a blank map of
   this area exceeds with probability :attr:`DetectorConfig.false_alarm_per_map`.
5. **Detections.** Each 8-connected region above the threshold is one inclusion (unless its raised cells all lie
   in the map's first or last row or column: the SPS ring over the specimen's edge), or one per maximum of the
   smallest disc's significance standing :attr:`DetectorConfig.split_snr` above the level joining it to a higher
   one (two neighbours' halos join in the larger discs). Each carries its significance (SNR: its peak, in σ of the
   filtered noise) and its per-map false-alarm probability (the chance that a blank map of this area shows a peak
   that high), its centroid weighted by the excess over the background, its extent (the cells raised by at least
   half its peak excess that join it, within the smallest disc of it) and its contrast (peak over the local
   background). On a partial map (an adaptive planner's, with the tissue it never measured named), regions that only
   unmeasured cells part, their peaks within one inclusion's breadth, are one inclusion seen in pieces
   (:attr:`DetectorConfig.join_gap_mm`, :attr:`DetectorConfig.join_span_mm`).

Our own code; the background / matched filter / extreme-value recipe is the standard one of source detection.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from models.background import BACKGROUND_DEGREE, MAD_TO_SIGMA, fit_background

# no scipy.ndimage (models.grid_filters does its three operations, to the bit) and scipy.optimize only in the
# function that fits a false-alarm law: scipy.ndimage alone takes ~0.16 s to import, on the start-up path of every
# process that publishes a map (a composed simulation included)
from models.false_alarm import (
    ADAPTIVE_GUMBEL_LOC,
    ADAPTIVE_GUMBEL_SCALE,
    ADAPTIVE_REFERENCE_AREA_MM2,
    CAMERA_GUMBEL_LOC,
    CAMERA_GUMBEL_SCALE,
    CAMERA_REFERENCE_AREA_MM2,
    FALSE_ALARM_LAWS,
    GUMBEL_LOC,
    GUMBEL_SCALE,
    PARTIAL_MAP_LAWS,
    REFERENCE_AREA_MM2,
    false_alarm_law,
    fit_false_alarm_law,
)
from models.grid_filters import dilate, disc_sum, label8
from models.peaks import joined_across, peak_parts
from models.stiffness_map import Inclusion, MapSnapshot, fill_gaps, nanmedian_stack

__all__ = ["ADAPTIVE_GUMBEL_LOC", "ADAPTIVE_GUMBEL_SCALE", "ADAPTIVE_REFERENCE_AREA_MM2", "BACKGROUND_DEGREE",
           "CAMERA_GUMBEL_LOC", "CAMERA_GUMBEL_SCALE", "CAMERA_REFERENCE_AREA_MM2", "FALSE_ALARM_LAWS", "GUMBEL_LOC",
           "GUMBEL_SCALE", "PARTIAL_MAP_LAWS", "REFERENCE_AREA_MM2", "DetectorConfig", "Detection",
           "describe", "detect", "false_alarm_law", "with_law_of", "false_alarm_probability", "fit_false_alarm_law", "peak_significance", "significance",
           "threshold_for"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

@dataclass(frozen=True, slots=True)
class DetectorConfig:
    """What the detector looks for and how sure it must be (module doc)."""

    radii_mm: tuple[float, ...] = (2.5, 3.5, 5.0, 7.0)
    """Matched-filter disc radii: the inclusion sizes of interest."""
    false_alarm_per_map: float = 0.003
    """Probability that a map without inclusions (of the calibration's kind) shows a detection: 0.3 % (threshold
    4.4 σ on a 48 mm square). On the tuning sets 0.5 % called one of the forty blank maps and 0.2 % found no more."""
    candidate_snr: float = 4.0
    """Cells whose significance exceeds this (σ) at any scale, and that are raised by more than a cell's noise, are
    candidates, left out of the background and noise. A level of its own, not a fraction of the threshold: the blank maps' law
    (step 4) must not depend on the threshold it sets, and a lower level masks the upper tail of a blank map's
    noise, which shifts its median down and makes the rest look more significant."""
    iterations: int = 3
    min_valid_cells: int = 12
    """Fewer valid cells than this: no detection (too little map to tell background from noise)."""
    gumbel: tuple[float, float, float] = (GUMBEL_LOC, GUMBEL_SCALE, REFERENCE_AREA_MM2)
    """(location, scale, reference area) of the blank maps' largest significance; default: the air-float probe's
    (another probe's maps take theirs from :func:`false_alarm_law`)."""
    spike_ratio: float = 2.5
    """A cell reading more than this times the median of its neighbours is no tissue under the probe's footprint
    (the indenter, 4 mm in radius, is wider than a cell, so a reading cannot jump so far in one cell: it is the
    probe at an edge reading the table, or a fault) and is left out as if unmeasured."""
    split_snr: float = 3.0
    """A region above the threshold is cut into one inclusion per maximum of the smallest disc's significance that
    stands this much (σ) above the level joining it to a higher one (models.peaks): two neighbours' halos join in
    the larger discs."""
    noise_floor_rel: float = 0.01
    """The filtered noise scale is at least this (relative): a map smoother than the probe can measure (a synthetic
    one, a quantised one) does not make every wrinkle significant."""
    join_gap_mm: float = 6.0
    """On a partial map (:func:`detect`'s ``unmeasured``), regions above the threshold that only unmeasured tissue
    parts, by this much or less, are one inclusion seen in pieces (two segments of a sparse lattice across one
    inclusion, the cells between never measured) and are reported once, not cut by maxima (0: off). 6 mm: the
    blind columns between every other line of the raster (bench/adaptive_staged.py, fresh set 14500: over its ten
    sparse lattices' maps the false positives, mostly such pieces, fell from 315 to 113; at 0.20 of the raster's
    probes from 59 to 38, the misses the same; 10 mm found no more)."""
    guard_noise_ratio: float = 0.6
    """On a partial map (``estimate_from`` leaves out valid cells) the background is fitted again without the cells
    :attr:`guard_snr` above a plane (models.background.raised_above_plane), kept when its noise is below this fraction
    of the first fit's (0: off). Corner inclusions holding a third of a sparse lattice's cells bend the quadratic and
    inflate the noise 3-5 fold (spent seed 15005); a dome's top left out lowers it little (15016). BENCHMARKS.md."""
    guard_snr: float = 2.5
    """The guard's level in robust σ above the plane (2.5-3 scored the same on the planner's maps)."""
    join_span_mm: float = 10.0
    """Pieces joined across unmeasured tissue (:attr:`join_gap_mm`) have their peaks this close or closer: the
    pieces of one inclusion lie within its breadth, two neighbours' farther apart."""

    def __post_init__(self) -> None:
        if not self.radii_mm or min(self.radii_mm) <= 0:
            raise ValueError(f"DetectorConfig.radii_mm: need positive radii, got {self.radii_mm}")
        if not 0 < self.false_alarm_per_map < 1:
            raise ValueError(f"DetectorConfig.false_alarm_per_map: need 0 < p < 1, got {self.false_alarm_per_map}")
        if not self.candidate_snr > 0:
            raise ValueError(f"DetectorConfig.candidate_snr: need > 0, got {self.candidate_snr}")
        if not self.noise_floor_rel > 0:
            raise ValueError(f"DetectorConfig.noise_floor_rel: need > 0, got {self.noise_floor_rel}")
        if not self.join_gap_mm >= 0:
            raise ValueError(f"DetectorConfig.join_gap_mm: need >= 0, got {self.join_gap_mm}")
        if not self.join_span_mm >= 0:
            raise ValueError(f"DetectorConfig.join_span_mm: need >= 0, got {self.join_span_mm}")
        if not (self.guard_noise_ratio >= 0 and self.guard_snr > 0):
            raise ValueError(f"DetectorConfig.guard_noise_ratio/guard_snr: need >= 0 and > 0, got "
                             f"{self.guard_noise_ratio}, {self.guard_snr}")
        if self.iterations < 1:
            raise ValueError(f"DetectorConfig.iterations: need >= 1, got {self.iterations}")


@dataclass(frozen=True, slots=True)
class Detection:
    """What the detector found and what it compared against."""

    inclusions: list[Inclusion]
    baseline: float
    """Median of the background surface over the valid cells (the map's unit); NaN without a map."""
    noise_rel: float
    """Robust relative noise of one cell against the background (σ of the log-residual)."""
    threshold_snr: float
    """The significance a detection had to exceed on this map."""
    significance: FloatArray = field(repr=False)
    """(ny, nx) largest significance over the scales (NaN where no filter had enough cells)."""
    background: FloatArray = field(repr=False)
    """(ny, nx) the background surface (the map's unit), NaN outside the valid cells."""
    candidates: BoolArray = field(repr=False)
    """(ny, nx) cells left out of the background and noise estimates."""
    grid: FloatArray = field(repr=False)
    """(ny, nx) the map detected on (gaps of one cell filled: models.stiffness_map.fill_gaps), NaN where invalid."""
    residual: FloatArray = field(repr=False)
    """(ny, nx) log(map / background), NaN where invalid."""
    area_mm2: float = math.nan
    """The map's valid area (the false-alarm law's)."""


def with_law_of(cfg: DetectorConfig, model: str, *, partial: bool = False, budget: bool = False) -> DetectorConfig:
    """``cfg`` with the false-alarm law measured for ``model``'s probe (:func:`false_alarm_law`, ``partial`` and
    ``budget`` as there); ``cfg`` as it is for a probe no law was measured for (the caller says so: its stated
    false-alarm rate is then not that map's)."""
    law = false_alarm_law(model, partial=partial, budget=budget)
    return cfg if law is None else replace(cfg, gumbel=law)


def threshold_for(area_mm2: float, cfg: DetectorConfig) -> float:
    """The significance a blank map of ``area_mm2`` exceeds with probability ``cfg.false_alarm_per_map``."""
    loc, scale, ref = cfg.gumbel
    shift = scale * math.log(max(area_mm2, 1e-9) / ref)
    return loc + shift - scale * math.log(-math.log1p(-cfg.false_alarm_per_map))


def false_alarm_probability(snr: float, area_mm2: float, cfg: DetectorConfig) -> float:
    """The chance that a blank map of ``area_mm2`` shows a peak significance of ``snr`` or more."""
    loc, scale, ref = cfg.gumbel
    z = (snr - loc - scale * math.log(max(area_mm2, 1e-9) / ref)) / scale
    return -math.expm1(-math.exp(-z))


@functools.lru_cache(maxsize=64)
def _disc(radius_mm: float, cell_mm: float) -> FloatArray:
    """The cells of a disc (1.0 inside), read-only: made once per radius and cell size (a detection asks for each
    at every map published)."""
    n = max(0, int(math.floor(radius_mm / cell_mm + 1e-9)))
    yy, xx = np.mgrid[-n : n + 1, -n : n + 1] * cell_mm
    disc = np.asarray(xx**2 + yy**2 <= radius_mm**2 + 1e-9, dtype=np.float64)
    disc.setflags(write=False)
    return disc


def _drop_spikes(grid: FloatArray, ratio: float) -> FloatArray:
    """``grid`` with NaN where a cell reads more than ``ratio`` times the median of its valid neighbours (module
    doc); a copy."""
    padded = np.pad(grid, 1, constant_values=np.nan)
    ny, nx = grid.shape
    stack = np.stack([padded[dy : dy + ny, dx : dx + nx] for dy in range(3) for dx in range(3) if (dy, dx) != (1, 1)])
    around = nanmedian_stack(stack)  # a cell without valid neighbours: NaN, kept
    spike = np.isfinite(grid) & (around > 0) & (grid > ratio * around)
    return np.where(spike, np.nan, grid)


def _spread(values: FloatArray) -> tuple[float, float]:
    """(median, 1.4826 MAD): the centre and robust σ of the cells left once the candidates are masked."""
    centre = float(np.median(values))
    return centre, MAD_TO_SIGMA * float(np.median(np.abs(values - centre)))


def significance(residual: FloatArray, valid: BoolArray, use: BoolArray, cell_mm: float,
                 radii_mm: tuple[float, ...], floor: float) -> list[FloatArray]:
    """Per radius, the residual's disc mean times sqrt(valid cells in the disc), less that quantity's median over the
    ``use`` cells, in units of its robust scale there (at least ``floor``); NaN where the disc holds fewer than a
    third of its cells."""
    r = np.where(valid, residual, 0.0)
    ok = valid.astype(np.float64)
    out = []
    for radius in radii_mm:
        k = _disc(radius, cell_mm)
        n = disc_sum(ok, k)
        total = disc_sum(r, k)
        with np.errstate(invalid="ignore", divide="ignore"):
            stat = np.where(n >= max(1.0, k.sum() / 3), total / np.sqrt(n), np.nan)
        ref = stat[use & np.isfinite(stat)]
        if ref.size < 5:
            out.append(np.full(stat.shape, np.nan))
            continue
        centre, scale = _spread(ref)
        out.append((stat - centre) / max(scale, floor))
    return out


def detect(snapshot: MapSnapshot, cfg: DetectorConfig | None = None, *, threshold_scale: float = 1.0,
           estimate_from: BoolArray | None = None, unmeasured: BoolArray | None = None) -> Detection:
    """The inclusions of a map (module doc), most significant first.

    ``threshold_scale`` multiplies the threshold (below 1: the suspects worth a closer look, as an adaptive planner
    asks for). ``estimate_from``: the cells whose values are a fair sample of the tissue, the only ones the
    background and noise may be estimated from (an adaptive planner's blind sweeps; default: every valid cell);
    when they leave out a valid cell the map is partial, and the background's fit starts robustly
    (models.background.fit_background). ``unmeasured``: cells of the tissue nobody measured (an adaptive planner's
    blind cells; not cells off the specimen), across which regions :attr:`DetectorConfig.join_gap_mm` apart or less
    are one inclusion (default: none; a whole map's detections do not depend on it). Non-positive stiffness values
    are not valid cells (eq. 7 gives none on a sound map). Raises ValueError on a config it cannot use."""
    cfg = cfg or DetectorConfig()
    grid = fill_gaps(_drop_spikes(np.asarray(snapshot.stiffness, dtype=np.float64), cfg.spike_ratio))
    valid = np.isfinite(grid) & (grid > 0)
    shape = grid.shape
    nan = np.full(shape, np.nan)
    empty = Detection([], math.nan, math.nan, math.nan, nan, nan, np.zeros(shape, dtype=bool), nan, nan)
    fair = valid if estimate_from is None else valid & np.asarray(estimate_from, dtype=bool)
    if fair.sum() < cfg.min_valid_cells:
        return empty
    cell = float(snapshot.resolution_mm)
    logs = np.where(valid, np.log(np.where(valid, grid, 1.0)), np.nan)
    area = float(valid.sum()) * cell * cell
    threshold = threshold_scale * threshold_for(area, cfg)
    partial = not np.array_equal(fair, valid)   # some valid cell is no fair sample of the tissue
    bg, residual, sig, candidates, noise = _estimate(logs, valid, fair, snapshot, cfg, partial, 0.0)
    if partial and cfg.guard_noise_ratio > 0:
        guarded = _estimate(logs, valid, fair, snapshot, cfg, partial, cfg.guard_snr)
        if guarded[4] < cfg.guard_noise_ratio * noise:
            bg, residual, sig, candidates, noise = guarded
    best = np.full(shape, -np.inf)
    for s in sig:
        best = np.fmax(best, np.nan_to_num(s, nan=-np.inf))
    best = np.where(np.isfinite(best) & valid, best, np.nan)
    background = np.where(valid, np.exp(bg), np.nan)
    baseline = float(np.median(background[valid]))
    det = Detection([], baseline, noise, threshold, best, background, candidates, grid, residual, area)
    labels, n = label8(np.nan_to_num(best, nan=-np.inf) > threshold)
    # the smallest disc's significance separates neighbours whose larger discs' halos join
    finest = np.nan_to_num(sig[int(np.argmin(cfg.radii_mm))], nan=-np.inf)
    found = []
    for members in _groups(det, labels, n, valid, unmeasured, cell, cfg):
        region = np.isin(labels, members)
        parts = peak_parts(finest, region, region, cfg.split_snr) if len(members) == 1 else [region]
        if len(parts) < 2 or any(p.sum() < 2 for p in parts):
            parts = [region]
        found += [describe(det, snapshot, p, cfg, part=len(parts) > 1) for p in parts if not _edge_row(det, p)]
    return replace(det, inclusions=sorted(found, key=lambda inc: -inc.snr))


def _estimate(logs: FloatArray, valid: BoolArray, fair: BoolArray, snapshot: MapSnapshot, cfg: DetectorConfig,
              partial: bool, guard_snr: float
              ) -> tuple[FloatArray, FloatArray, list[FloatArray], BoolArray, float]:
    """Steps 1-3 of the module doc: (background, residual, significance per radius, candidates, noise), the
    background fitted with models.background's guard at ``guard_snr`` (0: none)."""
    candidates = np.zeros(logs.shape, dtype=bool)
    cell = float(snapshot.resolution_mm)
    for _ in range(cfg.iterations):
        use = fair & ~candidates
        if use.sum() < cfg.min_valid_cells:
            use = fair
        bg = fit_background(logs, use, snapshot.x_mm, snapshot.y_mm, robust_start=partial, guard_snr=guard_snr)
        residual = logs - bg
        sig = significance(residual, valid, use, cell, cfg.radii_mm, cfg.noise_floor_rel)
        hot = np.zeros(logs.shape, dtype=bool)
        for s in sig:
            hot |= np.nan_to_num(s, nan=-np.inf) > cfg.candidate_snr
        # of a significant region, the cells raised by more than a cell's noise: the inclusion and its halo, not
        # the healthy cells a large disc reaches past it
        spread = max(_spread(residual[use])[1], cfg.noise_floor_rel)
        new = hot & valid & (np.nan_to_num(residual, nan=-np.inf) > spread)
        if np.array_equal(new, candidates):
            break
        candidates = new
    use = fair & ~candidates
    noise = _spread(residual[use] if use.any() else residual[fair])[1]
    return bg, residual, sig, candidates, noise


def _groups(det: Detection, labels: npt.NDArray[np.int_], n: int, valid: BoolArray, unmeasured: BoolArray | None,
            cell: float, cfg: DetectorConfig) -> list[list[int]]:
    """The regions 1..n above the threshold, each alone (a whole map: nothing is named unmeasured), or on a partial
    map joined where only unmeasured tissue parts them (module doc, step 5; models.peaks.joined_across), an edge
    row dropped first (its reading is the table's, no piece of anything)."""
    gap = int(round(cfg.join_gap_mm / cell))
    if unmeasured is None or gap == 0 or n < 2:
        return [[k] for k in range(1, n + 1)]
    keep = [k for k in range(1, n + 1) if not _edge_row(det, labels == k)]
    best = np.nan_to_num(det.significance, nan=-np.inf)
    peaks = {k: np.unravel_index(int(np.argmax(np.where(labels == k, best, -np.inf))), labels.shape) for k in keep}
    span = (cfg.join_span_mm / cell) ** 2

    def near(a: int, b: int) -> bool:
        return float((peaks[a][0] - peaks[b][0]) ** 2 + (peaks[a][1] - peaks[b][1]) ** 2) <= span + 1e-9

    return joined_across(labels, keep, np.asarray(unmeasured, dtype=bool) & ~valid, gap, near)


def peak_significance(det: Detection, floor: float = 2.0) -> float:
    """The largest significance on the map that the detector could report: the highest peak of the regions above
    ``floor`` that are not an edge row (:func:`detect`), else the map's largest significance. A blank map's false
    alarm is this exceeding the threshold; bench/detector_calibration.py fits the law of it."""
    sig = np.nan_to_num(det.significance, nan=-np.inf)
    labels, n = label8(sig > floor)
    tops = [float(sig[labels == k].max()) for k in range(1, n + 1) if not _edge_row(det, labels == k)]
    return max(tops) if tops else min(floor, float(sig.max()))


def _edge_row(det: Detection, region: BoolArray) -> bool:
    """Whether the cells raised by half the region's peak or more all lie in the map's first or last row or column:
    the SPS ring hanging over the specimen's edge reads the table there (one row, the next one healthy), which an
    inclusion under the probe's 4 mm indenter cannot do (it raises two cells or more across)."""
    excess = np.expm1(np.nan_to_num(det.residual, nan=-np.inf))
    peak = float(excess[region].max())
    core = np.argwhere(region & (excess >= 0.5 * peak))
    if core.size == 0 or peak <= 0:
        return False
    ny, nx = region.shape
    rows, cols = core[:, 0], core[:, 1]
    return bool((rows == 0).all() or (rows == ny - 1).all() or (cols == 0).all() or (cols == nx - 1).all())


def describe(det: Detection, snapshot: MapSnapshot, region: BoolArray, cfg: DetectorConfig,
             part: bool = False) -> Inclusion:
    """One detected region (non-empty ``region`` cells of ``det``'s grid) as an inclusion (module doc, step 5).
    ``part``: the region is one part of a region cut in two or more, and its extent stays within the smallest disc
    of it (the raised cells past the cut are the other part's)."""
    valid = np.isfinite(det.residual)
    cell = float(snapshot.resolution_mm)
    gy, gx = np.meshgrid(snapshot.y_mm, snapshot.x_mm, indexing="ij")
    excess = np.where(valid, np.expm1(np.where(valid, det.residual, 0.0)), 0.0)
    peak_excess = float(excess[region].max())
    core = region
    if peak_excess > 0:   # the cells raised by half the peak or more that join the region
        half, _ = label8(excess >= 0.5 * peak_excess)
        core = np.isin(half, np.unique(half[region & (half > 0)]))
        if part:
            core &= dilate(region, _disc(min(cfg.radii_mm), cell) > 0)
    own = core & region if (core & region).any() else core   # the centroid from this region's own raised cells
    w = np.clip(excess[own], 0.0, None)
    if not w.sum() > 0:
        w = np.ones(int(own.sum()))
    snr = float(np.nanmax(np.where(region, det.significance, np.nan)))
    i_peak = np.unravel_index(int(np.argmax(np.where(region, excess, -np.inf))), region.shape)
    cells = int(core.sum())
    return Inclusion(
        x_mm=float(np.sum(w * gx[own]) / w.sum()),
        y_mm=float(np.sum(w * gy[own]) / w.sum()),
        radius_mm=math.sqrt(cells * cell * cell / math.pi),
        contrast=1.0 + peak_excess,
        peak=float(det.grid[i_peak]),
        area_mm2=cells * cell * cell,
        cells=cells,
        snr=snr,
        false_alarm=false_alarm_probability(snr, det.area_mm2, cfg),
    )
