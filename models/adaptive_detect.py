"""When has adaptive palpation *found* what there is to find: a stop rule on detection, not on classifying every cell.

:func:`models.adaptive.should_stop` is LSE's: stop when no cell of the belief still straddles the level. On the
honest world that is a coverage rule at the scale of the kernel's length (a few mm), so the planner spent about half
the raster's probes making sure of tissue where nothing was. The question a palpation answers is narrower: *is there
an inclusion, and where*. Two things must hold before that answer is good enough:

* **nothing of interest can hide.** A sweep senses an inclusion only near it: the excess stiffness of an inclusion
  reaches about a millimetre or two past its edge (bench/airfloat_reach.py on the raster's maps: median 2 mm, a
  quarter of them 1 mm or less, mostly the deeper ones; ``reach_spread_mm`` averages over that). An inclusion of
  radius ``r`` whose centre lies within ``r`` plus that sensing reach of a measured cell raised that cell; one
  farther from every measured cell could be anywhere there unseen. ``reach_mm`` is that distance for the smallest
  radius of interest (2.5 + 1.5 mm); it grows with the radius over ``radius_span_mm`` (to 7 mm: a large inclusion is
  sensed from farther, a small deep one only from near; one reach for all, 6 mm, let small ones hide 4-6 mm from a
  sweep). With the inclusion's centre uniform over the region (no prior on where tumours are) and its radius uniform
  over the span, the probability that it hides is the fraction of the region farther than its reach from every
  measured cell, averaged over the radii (:func:`miss_probability`). Stop only when that is below
  ``miss_probability``. (Garg et al. 2016 and Gotovos et al. 2013 stop on the belief alone; a GP with a length scale
  shorter than that reach cannot vouch for it, which is why the LSE rule costs coverage.)
* **every candidate is resolved.** A candidate is a region the map's own detector reports when its false-alarm
  rate per map is loosened to ``suspect_false_alarm`` (a weak inclusion seen from a sweep past its edge rises less
  than the map's bar); it is confirmed when it passes the map's bar (``false_alarm_per_map``), and dismissed when,
  its boundary sampled, it does not. It is
  resolved when the points on the edge of its disc on all four sides (one cell out for a small one:
  :func:`open_sides`) have been measured: its boundary is sampled, so its centroid and extent are the map's and
  not the kernel's guess; when a side is still stiff the candidate grows and opens the next side out.
  A *detected* inclusion is resolved only once its disc is measured densely (every cell within ``interior_gap_mm``
  of a measured one, columns 6 mm apart by default: :func:`interior_gaps`): between sparse sweeps the map is the
  GP's guess, which joins two neighbours into one blob and shows no dip it never measured.
  A *near miss* (a suspect that is no detection but whose false-alarm probability by the detector's law is at most
  ``near_miss_false_alarm``:
  :func:`near_misses`) is resolved only once its disc is measured at the raster's density (``near_miss_gap_mm``):
  whether a weak inclusion crosses the threshold turns on whether a cell near its middle was measured.

The acquisition follows the same two needs: resolve candidates first (a sweep at an open side), then cover: a sweep
of the staggered covering lattice that still reveals hidden area (models.adaptive_cover: the coverage functions live
there), the most of it, ties to the nearest, and once none does, the sweep anywhere that leaves the least area where
an inclusion could hide (:func:`coverage_gain`, a greedy set cover; with ``near_best`` < 1 the nearest of the
near-best). Seed grid and covering sweeps are chosen without looking at stiffness, so their cells are a fair sample
of the tissue: the detector's background and noise come from them (:func:`detect_candidates`), not from every
measured cell (the resolving sweeps go where it is stiff), and of those only from the cells that are no candidates
(models.detector).

Detection uses measured cells where they exist (the per-cell median of the sweeps' samples) and the GP mean only
within ``fill_mm`` of a measured cell (:func:`detection_map`): the smoothed mean alone widens and merges blobs, and
far from data it only repeats the prior. A detection whose measured cells show two maxima with a measured dip between
them is two inclusions (models.adaptive_split, ``split_prominence``): the matched filter can join two neighbours'
halos. Our own code, written from the papers' ideas.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from models.adaptive import (
    Belief,
    PlannerConfig,
    footprint_cells,
    footprint_score,
    near_probed,
    next_probe,
    probe_points,
)
from models.adaptive_budget import most_likely
from models.adaptive_cover import (
    cover_lattice,
    coverage_gain,
    distance_to_measured,
    hidden,
    hidden_fractions,
    miss_probability,
    seed_design,
)
from models.adaptive_route import order_route
from models.adaptive_split import split_detections
from models.detector import Detection, DetectorConfig, detect, false_alarm_probability, with_law_of
from models.stiffness_map import Inclusion, MapSnapshot

__all__ = ["Decision", "candidate_map", "decide", "detect_candidates", "detection_map", "detector_config", "interior_gaps",
           "mask_gaps", "near_misses", "off_halos", "open_sides", "region_masks", "swept_cells", "unsensed"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def detection_map(measured: FloatArray, mean: FloatArray, resolution_mm: float, fill_mm: float) -> FloatArray:
    """The map inclusions are detected on: the measured value where a cell was measured, the GP mean within
    ``fill_mm`` of a measured cell, NaN farther (the prior there, not a measurement)."""
    meas = np.asarray(measured, dtype=np.float64)
    ok = np.isfinite(meas)
    near = distance_to_measured(ok, resolution_mm) <= fill_mm
    return np.where(ok, meas, np.where(near, np.asarray(mean, dtype=np.float64), np.nan))


def detector_config(cfg: PlannerConfig, suspect: bool = False) -> DetectorConfig:
    """The map detector's settings the planner detects with (the raster's own, its false-alarm rate the planner's;
    ``suspect``: at ``cfg.suspect_false_alarm``, the bar a region must pass to be worth resolving)."""
    rate = cfg.suspect_false_alarm if suspect else cfg.false_alarm_per_map
    # the planner's maps are partial: the law of its own blank maps where one was measured, a budgeted planner's own
    # (its sparser maps keep suspects it could not afford to resolve: a heavier tail)
    return with_law_of(DetectorConfig(false_alarm_per_map=rate), cfg.model, partial=True,
                       budget=cfg.budget_fraction > 0)


def candidate_map(belief: Belief, measured: FloatArray, counts: npt.NDArray[np.int64],
                  cfg: PlannerConfig) -> MapSnapshot:
    """The detection map (:func:`detection_map`) as a map snapshot: what :func:`detect_candidates` detects on, and
    what the planner shows after every probe."""
    grid = detection_map(measured, belief.mean, cfg.resolution_mm, cfg.fill_mm)
    return MapSnapshot(stiffness=grid, x_mm=belief.x_mm, y_mm=belief.y_mm, count=counts, spread=belief.std,
                       resolution_mm=cfg.resolution_mm)


def detect_candidates(belief: Belief, measured: FloatArray, counts: npt.NDArray[np.int64], cfg: PlannerConfig,
                      fair: FloatArray | None = None, suspect: bool = False) -> tuple[MapSnapshot, Detection]:
    """The detection map (:func:`detection_map`) as a map snapshot, and what the map detector
    (models.detector.detect, the raster's own) finds on it, its background and noise from the cells of ``fair``
    (measured by stiffness-blind sweeps: the resolving sweeps go where it is stiff, and the GP's guesses are smoother
    than any measurement) when it has any, else from the measured cells; a detection whose measured cells show two
    maxima split in two (``cfg.split_prominence``: models.adaptive_split). ``suspect``: at the detector's
    false-alarm rate ``cfg.suspect_false_alarm``, the regions worth a closer look (a weak inclusion seen from a sweep that
    passed its edge rises less than the detector's threshold; resolving it samples nearer its centre), never split
    (the split would only add sides to sample)."""
    snap = candidate_map(belief, measured, counts, cfg)
    observed = np.isfinite(measured)
    blind = observed if fair is None else np.isfinite(np.asarray(fair, dtype=np.float64))
    dcfg = detector_config(cfg, suspect)
    estimate = blind if blind.any() else observed
    unseen = ~np.isfinite(snap.stiffness)   # the region is tissue: what the map leaves blank nobody measured
    if cfg.fair_halo_mm > 0:
        estimate = off_halos(snap, estimate, detect(snap, detector_config(cfg), estimate_from=estimate,
                                                    unmeasured=unseen), cfg.fair_halo_mm, dcfg.min_valid_cells)
    det = detect(snap, dcfg, estimate_from=estimate, unmeasured=unseen)
    if cfg.split_prominence > 0 and not suspect:
        det = replace(det, inclusions=split_detections(det, snap, observed, dcfg, prominence_k=cfg.split_prominence))
    return snap, det


def off_halos(snap: MapSnapshot, fair: BoolArray, detected: Detection, halo_mm: float, min_cells: int) -> BoolArray:
    """``fair`` less the cells within ``halo_mm`` past the disc of each of ``detected``'s inclusions: a blind sweep
    over a detection's halo reads part of it (the indenter is 4 mm in radius), and on a sparse map those cells are
    a large share of the background's sample, which they raise and widen (the shipped phantom's noise 0.07-0.10
    against the raster's 0.045). ``fair`` as it is when fewer than ``min_cells`` would be left."""
    gx, gy = np.meshgrid(snap.x_mm, snap.y_mm)
    keep = np.array(fair, dtype=bool)
    for inc in detected.inclusions:
        keep &= (gx - inc.x_mm) ** 2 + (gy - inc.y_mm) ** 2 > (inc.radius_mm + halo_mm) ** 2
    return keep if np.count_nonzero(keep & np.isfinite(snap.stiffness)) >= min_cells else np.array(fair, dtype=bool)


def near_misses(suspects: Sequence[Inclusion], detected: Detection, cfg: PlannerConfig) -> list[Inclusion]:
    """The suspects that are no detection but came close: a blank map of their map's area would show a peak as
    significant with probability at most ``cfg.near_miss_false_alarm`` (the detector's own law,
    models.detector.false_alarm_probability, on the map of ``detected``), and no detection's centre lies inside
    their disc (a detection's halo is no inclusion of its own)."""
    if cfg.near_miss_false_alarm <= 0 or not np.isfinite(detected.area_mm2):
        return []
    dcfg = detector_config(cfg)
    return [c for c in suspects
            if false_alarm_probability(c.snr, detected.area_mm2, dcfg) <= cfg.near_miss_false_alarm
            and not any((d.x_mm - c.x_mm) ** 2 + (d.y_mm - c.y_mm) ** 2 <= c.radius_mm**2
                        for d in detected.inclusions)]


def open_sides(candidates: Sequence[Inclusion], observed: BoolArray, x_mm: FloatArray, y_mm: FloatArray,
               region_mm: tuple[float, float, float, float], resolution_mm: float) -> list[tuple[float, float]]:
    """Where a candidate is not yet sampled: for each candidate (its disc, centre and radius), the points on its
    disc's edge (at least one cell from its centre) to the left, right, below and above, where no cell within one
    cell of the point was measured and the point lies inside the region. A probe at an edge point tells where the
    stiff tissue ends (or, when it is still stiff, grows the candidate and opens the next point out)."""
    x0, y0, x1, y1 = region_mm
    gx, gy = np.meshgrid(x_mm, y_mm)
    mx, my = gx[observed], gy[observed]
    out = []
    for c in candidates:
        d = max(resolution_mm, c.radius_mm)
        for px, py in [(c.x_mm - d, c.y_mm), (c.x_mm + d, c.y_mm), (c.x_mm, c.y_mm - d), (c.x_mm, c.y_mm + d)]:
            if not (x0 <= px <= x1 and y0 <= py <= y1):
                continue
            if not np.any((mx - px) ** 2 + (my - py) ** 2 <= resolution_mm**2 + 1e-9):
                out.append((px, py))
    return out


def interior_gaps(candidates: Sequence[Inclusion], observed: BoolArray, x_mm: FloatArray, y_mm: FloatArray,
                  region_mm: tuple[float, float, float, float], resolution_mm: float, gap_mm: float,
                  footprint: int) -> list[tuple[float, float]]:
    """Where a detected inclusion's disc is not yet measured densely enough: for each candidate whose disc has cells
    farther than ``gap_mm`` from every measured cell, the centre of the sweep of ``footprint`` cells (along y) that
    crosses the most of them (nearest the candidate's centre of those), kept inside the region. Between two sweeps
    12 mm apart the map cannot tell one wide blob from two neighbours, nor a weak inclusion's dip from its halo; with
    columns ``2 * gap_mm`` apart over it, the map there is measured about as densely as the raster's."""
    gx, gy = np.meshgrid(x_mm, y_mm)
    discs = [((gx - c.x_mm) ** 2 + (gy - c.y_mm) ** 2 <= max(c.radius_mm, resolution_mm) ** 2,
              (c.x_mm, c.y_mm)) for c in candidates]
    return mask_gaps(discs, observed, x_mm, y_mm, region_mm, resolution_mm, gap_mm, footprint)


def region_masks(detected: Detection, x_mm: FloatArray,
                 y_mm: FloatArray) -> list[tuple[BoolArray, tuple[float, float]]]:
    """Each detection's whole region above the map's threshold (8-connected) and the detection's centre: where the
    matched filter joins a strong inclusion's halo to a neighbour's, the region reaches past the detection's disc,
    and only a measured dip there lets models.adaptive_split part them (tuning seed 118: an r 5.6 x3.8 inclusion
    18 mm from an x5.1 one, joined in every draw)."""
    sig = np.nan_to_num(detected.significance, nan=-np.inf)
    if not detected.inclusions or sig.size == 0:
        return []
    labels, _ = ndimage.label(sig > detected.threshold_snr, structure=np.ones((3, 3), dtype=bool))
    out = []
    for inc in detected.inclusions:
        k = labels[int(np.argmin(np.abs(y_mm - inc.y_mm))), int(np.argmin(np.abs(x_mm - inc.x_mm)))]
        if k > 0:
            out.append((labels == k, (inc.x_mm, inc.y_mm)))
    return out


def mask_gaps(masks: Sequence[tuple[BoolArray, tuple[float, float]]], observed: BoolArray, x_mm: FloatArray,
              y_mm: FloatArray, region_mm: tuple[float, float, float, float], resolution_mm: float, gap_mm: float,
              footprint: int) -> list[tuple[float, float]]:
    """For each (cells, centre) of ``masks`` with cells farther than ``gap_mm`` from every measured cell, the centre
    of the sweep of ``footprint`` cells (along y) that crosses the most of them, nearest the centre of those, kept
    inside the region (:func:`interior_gaps`)."""
    x0, y0, x1, y1 = region_mm
    gx, gy = np.meshgrid(x_mm, y_mm)
    dist = distance_to_measured(observed, resolution_mm)
    half = 0.5 * footprint * resolution_mm
    out = []
    for cells, (cx, cy) in masks:
        r2 = (gx - cx) ** 2 + (gy - cy) ** 2
        gap = cells & (dist > gap_mm + 1e-9)
        if not gap.any():
            continue
        # the sweep (along y) over the most gap cells, the one nearest the candidate's centre of those
        hits = ndimage.correlate1d(gap.astype(np.float64), np.ones(footprint), axis=0, mode="constant")
        hits[~gap] = 0.0
        i = int(np.argmin(np.where(hits >= hits.max(), r2, np.inf)))
        y = min(max(float(gy.flat[i]), y0 + half), y1 - half) if y1 - y0 >= 2 * half else float(gy.flat[i])
        out.append((min(max(float(gx.flat[i]), x0), x1), y))
    return out


def swept_cells(observed: BoolArray, x_mm: FloatArray, y_mm: FloatArray, probed: Sequence[tuple[float, float]],
                cfg: PlannerConfig) -> BoolArray:
    """The cells that count as sensed: those measured, and those every sweep made (or given up) crossed, its samples
    or not: one at the specimen's edge whose samples landed a cell inward would otherwise be asked for again 2 mm
    over and over (tuning seed 119: 5 sweeps)."""
    covered = np.array(observed, dtype=bool)
    gx, gy = np.meshgrid(x_mm, y_mm)
    half = 0.5 * max(cfg.sweep_mm, cfg.resolution_mm)
    for ux, uy in probed:
        covered |= (np.abs(gx - ux) <= 0.5 * cfg.resolution_mm) & (np.abs(gy - uy) <= half)
    return covered


def unsensed(observed: BoolArray, x_mm: FloatArray, y_mm: FloatArray, probed: Sequence[tuple[float, float]],
             cfg: PlannerConfig) -> tuple[list[tuple[float, float]], BoolArray]:
    """What the planner could not have sensed when it stops: for each reach of interest (``cfg.reaches()``,
    smallest first), the fraction of the region farther than it from every sensed cell (:func:`swept_cells`), where
    an inclusion of that reach could lie unseen; and the cells where one of the smallest radius could, at
    ``cfg.reach_mm`` (its centre there). Their mean is :func:`models.adaptive_cover.miss_probability`, the number
    the stop rule holds under ``cfg.miss_probability``: small, not nothing, and only as true as the reaches
    (``reach_spread_mm``; bench/airfloat_reach.py measures them on raster maps)."""
    covered = swept_cells(observed, x_mm, y_mm, probed, cfg)
    reaches = cfg.reaches()
    fractions = list(zip(reaches, hidden_fractions(covered, cfg.resolution_mm, reaches), strict=True))
    return fractions, hidden(covered, cfg.resolution_mm, cfg.reach_mm)


def _priorities(points: Sequence[tuple[float, float]], suspects: Sequence[Inclusion], detected: Detection,
                observed: BoolArray, belief: Belief, cfg: PlannerConfig) -> dict[tuple[float, float], float]:
    """For each open point, the smallest false-alarm probability (the detector's law on ``detected``'s map) of the
    candidates it serves: a suspect's open sides, a detection's disc or region, a near miss's disc (one candidate at
    a time, as :func:`decide` finds them together). A point no candidate claims (none should) ranks last (1)."""
    dcfg = detector_config(cfg)
    area = detected.area_mm2 if np.isfinite(detected.area_mm2) else float(observed.size) * cfg.resolution_mm**2
    args = (observed, belief.x_mm, belief.y_mm, cfg.region_mm, cfg.resolution_mm)
    k = footprint_cells(cfg)
    prio = dict.fromkeys(points, 1.0)

    def claim(found: Sequence[tuple[float, float]], c: Inclusion) -> None:
        p = false_alarm_probability(c.snr, area, dcfg)
        for q in found:
            if q in prio:
                prio[q] = min(prio[q], p)

    for c in suspects:
        claim(open_sides([c], *args), c)
        claim(interior_gaps([c], *args, cfg.near_miss_gap_mm, k), c)   # as a near miss
    for c in detected.inclusions:
        claim(interior_gaps([c], *args, cfg.interior_gap_mm, k), c)
    if cfg.region_gaps:
        by_centre = {(c.x_mm, c.y_mm): c for c in detected.inclusions}
        for mask, centre in region_masks(detected, belief.x_mm, belief.y_mm):
            claim(mask_gaps([(mask, centre)], *args, cfg.interior_gap_mm, k), by_centre[centre])
    return prio


@dataclass(frozen=True)
class Decision:
    """What the detection stop rule says after a probe: stop (and why), or the next probe point."""

    stop: bool
    why: str
    point: tuple[float, float] | None
    blind: bool
    """The point was chosen without looking at stiffness (a covering sweep): its cells are a fair sample of the
    tissue for the detector's background (:func:`detect_candidates`)."""
    miss: float
    """The probability that an inclusion of the smallest radius of interest hides (:func:`miss_probability`)."""
    open_sides: int
    """Sides of the candidates whose boundary is not yet sampled (:func:`open_sides`)."""
    kind: str = ""
    """What the point is for: ``resolving a candidate``, ``measuring a detection's disc``, ``measuring a near miss's
    disc``, ``covering, lattice``, ``covering`` or ``no sweep reveals more`` (the start of ``why``; empty when
    stopping)."""


def decide(belief: Belief, measured: FloatArray, counts: npt.NDArray[np.int64], probed: Sequence[tuple[float, float]],
           cfg: PlannerConfig, last: tuple[float, float] | None = None, fair: FloatArray | None = None,
           given_up: Sequence[tuple[float, float]] = ()) -> Decision:
    """The detection stop rule and acquisition (module doc). ``measured``: the per-cell measured value (NaN where
    no sample landed), ``counts`` its sample counts, ``probed``: the points probed or given up so far, ``last``:
    where the probe is now (the nearest of the near-best coverage sweeps is taken), ``fair``: the cells measured by
    stiffness-blind sweeps (:func:`detect_candidates`), ``given_up``: points the scanner refused for good (also in
    ``probed``): the cells their sweep would have crossed count as covered (as do those of every sweep made, its
    samples or not), or the planner would ask for the unreachable tissue until its budget ran out."""
    n = len(probed)
    observed = np.isfinite(measured)
    covered = swept_cells(observed, belief.x_mm, belief.y_mm, probed, cfg)
    miss = miss_probability(covered, cfg.resolution_mm, cfg.reaches())
    _, suspects = detect_candidates(belief, measured, counts, cfg, fair, suspect=True)
    found = suspects.inclusions

    def unprobed(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
        return [p for p in points
                if not near_probed(np.array([p[0]]), np.array([p[1]]), probed, cfg.min_separation_mm)[0]]

    def disc_gaps(discs: Sequence[Inclusion], gap_mm: float) -> list[tuple[float, float]]:
        """The sweeps over the most unmeasured cells of each disc, until every cell is within ``gap_mm``."""
        return unprobed(interior_gaps(discs, observed, belief.x_mm, belief.y_mm, cfg.region_mm, cfg.resolution_mm,
                                      gap_mm, footprint_cells(cfg)))

    sides = unprobed(open_sides(found, observed, belief.x_mm, belief.y_mm, cfg.region_mm, cfg.resolution_mm))
    _, detected = detect_candidates(belief, measured, counts, cfg, fair)
    interior = disc_gaps(detected.inclusions, cfg.interior_gap_mm) if cfg.interior_gap_mm > 0 else []
    if cfg.interior_gap_mm > 0 and cfg.region_gaps:   # and the gaps of the region the detector joined it into
        interior += [p for p in unprobed(mask_gaps(region_masks(detected, belief.x_mm, belief.y_mm), observed,
                                                   belief.x_mm, belief.y_mm, cfg.region_mm, cfg.resolution_mm,
                                                   cfg.interior_gap_mm, footprint_cells(cfg)))
                     if p not in interior]
    second = disc_gaps(near_misses(found, detected, cfg), cfg.near_miss_gap_mm)   # near_miss 0: none
    n_open = len(sides) + len(interior) + len(second)
    state = f"miss probability {miss:.3f}, {len(found)} candidates, {n_open} boundary sides open"
    if n >= cfg.max_probes:
        return Decision(True, f"probe budget spent ({n} probes; {state})", None, False, miss, n_open)
    # with a budget to spend, covering goes on past the tolerance while any inclusion of interest could still hide
    covered_enough = miss < cfg.miss_probability and not (cfg.spend_budget and cfg.budget_fraction > 0 and miss > 0)
    if n >= len(seed_design(cfg)) and covered_enough and not n_open:
        return Decision(True, f"found: {state} after {n - len(given_up)} probes", None, False, miss, n_open)
    if n_open:
        # every open point is asked for before the stop; the nearest first along a short route through them all
        # (models.adaptive_route), not candidate by candidate across the specimen and back
        kinds = {**{p: "measuring a near miss's disc" for p in second},
                 **{p: "measuring a detection's disc" for p in interior}, **{p: "resolving a candidate" for p in sides}}
        todo = list(kinds)
        if cfg.budget_fraction > 0 and cfg.max_probes - n < len(todo):   # the most likely candidates' first
            todo = most_likely(_priorities(todo, found, detected, observed, belief, cfg), cfg.max_probes - n)
        point = order_route(todo, last)[0]
        kind = kinds[point]
        return Decision(False, f"{kind} ({state})", point, False, miss, n_open, kind)
    x0, y0, x1, y1 = cfg.region_mm
    px, py = (np.clip(v, lo, hi) for v, lo, hi in zip(probe_points(belief, cfg), (x0, y0), (x1, y1), strict=True))
    near = near_probed(px, py, probed, cfg.min_separation_mm)   # where the probe would go (models.adaptive.inside)
    gain = coverage_gain(covered, cfg.resolution_mm, cfg.reaches(), footprint_cells(cfg))
    gain[~np.isfinite(footprint_score(belief, cfg))] = 0.0   # a sweep that would leave the region
    gain[near] = 0.0
    # the covering lattice's sweeps first (models.adaptive_cover), those that still reveal something; the greedy
    # choice over every sweep only once none does (the lattice's edges, or tissue a refused sweep left)
    lattice = np.zeros(gain.shape, dtype=bool)
    for iy, ix in cover_lattice(cfg):
        lattice[iy, ix] = True
    on_lattice = bool(np.any(gain[lattice] > 0))
    if on_lattice:
        gain = np.where(lattice, gain, 0.0)
    best = float(np.max(gain))
    if best > 0:
        ok = gain >= cfg.near_best * best
        if last is not None:
            d2 = np.where(ok, (px - last[0]) ** 2 + (py - last[1]) ** 2, np.inf)
            i = int(np.argmin(d2))
        else:
            i = int(np.argmax(ok))
        kind = "covering, lattice" if on_lattice else "covering"
        return Decision(False, f"{kind} ({state})", (float(px.flat[i]), float(py.flat[i])), True, miss, n_open, kind)
    kind = "no sweep reveals more"
    return Decision(False, f"{kind} ({state})", next_probe(belief, probed, cfg, observed), False, miss, n_open, kind)
