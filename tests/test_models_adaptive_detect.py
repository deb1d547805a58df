"""models.adaptive_detect: the detection stop rule (nothing of interest can hide, every candidate's boundary sampled),
its coverage acquisition, the detection map and the stiffness-blind baseline."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from models.adaptive import Belief, PlannerConfig
from models.adaptive_cover import coverage_gain, hidden, miss_probability, sweep_stencil
from models.adaptive_detect import (
    decide,
    detect_candidates,
    detection_map,
    detector_config,
    interior_gaps,
    mask_gaps,
    near_misses,
    off_halos,
    open_sides,
    region_masks,
    unsensed,
)
from models.detector import (
    FALSE_ALARM_LAWS,
    PARTIAL_MAP_LAWS,
    Detection,
    DetectorConfig,
    threshold_for,
)
from models.stiffness_map import Inclusion, MapSnapshot

REGION = (0.0, 0.0, 40.0, 40.0)   # 20 x 20 cells of 2 mm
SEEDS = [(10.0, 10.0), (30.0, 10.0), (10.0, 30.0), (30.0, 30.0)]
"""The seed grid of :func:`_cfg` (2 x 2): the points probed before the rule may stop."""


def _cfg(**kw: Any) -> PlannerConfig:
    # one reach, no interior or near-miss rule and the greedy cover alone unless a test asks: each rule on its own
    kw = {"radius_span_mm": 0.0, "interior_gap_mm": 0.0, "cover_column_mm": 0.0, "near_miss_false_alarm": 0.0, **kw}
    return PlannerConfig(REGION, sweep_mm=6.0, seed_spacing_mm=40.0, **kw)   # seed: 2 x 2 points


def _unmeasured() -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    return np.full((20, 20), np.nan), np.zeros((20, 20), dtype=np.int64)


def _belief(cfg: PlannerConfig, value: float = 10.0) -> Belief:
    xs, ys = cfg.grid()
    shape = (len(ys), len(xs))
    return Belief(xs, ys, np.full(shape, value), np.full(shape, 0.5), value, value * 1.2)


def test_hidden_is_what_lies_farther_than_the_reach_from_every_measured_cell() -> None:
    obs = np.zeros((20, 20), dtype=bool)
    obs[:, 0] = True   # one measured column at x = 1 mm
    h = hidden(obs, 2.0, 6.0)
    # column i is 2 i mm from the measured column: hidden from 2 i > 6, i.e. columns 4.. (8 mm) on
    assert not h[:, :4].any() and h[:, 4:].all()
    assert miss_probability(obs, 2.0, 6.0) == 16 / 20
    assert miss_probability(obs, 2.0, 8.0) == 15 / 20   # exactly at the reach is sensed
    assert miss_probability(np.zeros((3, 3), dtype=bool), 2.0, 6.0) == 1.0


def test_the_reach_grows_with_the_radius_and_the_miss_probability_averages_over_the_radii() -> None:
    assert _cfg(reach_mm=4.0, radius_span_mm=4.5).reaches() == [4.0 + 0.5 * i for i in range(10)]
    assert _cfg(reach_mm=4.0).reaches() == [4.0]
    obs = np.zeros((20, 20), dtype=bool)
    obs[:, 0] = True   # one measured column at x = 1 mm: column i is 2 i mm from it
    # reach 4: columns 3.. hidden (17 of 20); reach 6: 4.. (16); reach 8: 5.. (15)
    assert math.isclose(miss_probability(obs, 2.0, [4.0, 6.0, 8.0]), (17 + 16 + 15) / 60)
    cfg = _cfg(reach_mm=4.0, radius_span_mm=4.0)
    assert miss_probability(obs, 2.0, cfg.reaches()) < miss_probability(obs, 2.0, 4.0)   # a large one is seen farther
    gain = coverage_gain(obs, 2.0, [4.0, 6.0], 3)
    assert np.array_equal(gain, coverage_gain(obs, 2.0, 4.0, 3) + coverage_gain(obs, 2.0, 6.0, 3))


def test_the_reach_spread_weighs_every_radius_at_every_offset_and_a_near_reach_costs_more_than_a_far_one_saves(
        ) -> None:
    cfg = _cfg(reach_mm=4.0, radius_span_mm=1.0, reach_spread_mm=(-1.0, 0.0, 1.0))
    assert cfg.reaches() == [3.0, 3.5, 4.0, 4.0, 4.5, 5.0, 5.0, 5.5, 6.0]   # 4, 4.5, 5 each at -1, 0, +1
    obs = np.zeros((20, 20), dtype=bool)
    obs[:, 0] = True   # one measured column at x = 1 mm: column i is 2 i mm from it
    # reach 3: columns 2.. hidden (18 of 20); 4 and 5: 3.. (17); so the spread's mean is above the one reach's
    one = miss_probability(obs, 2.0, _cfg(reach_mm=4.0).reaches())
    spread = miss_probability(obs, 2.0, _cfg(reach_mm=4.0, reach_spread_mm=(-1.0, 0.0, 1.0)).reaches())
    assert one == 17 / 20 and math.isclose(spread, (18 + 17 + 17) / 60)
    # a reach given twice weighs twice in the sweeps' gain, as in the miss probability
    gain = coverage_gain(obs, 2.0, [4.0, 4.0, 6.0], 3)
    assert np.array_equal(gain, 2 * coverage_gain(obs, 2.0, 4.0, 3) + coverage_gain(obs, 2.0, 6.0, 3))
    with pytest.raises(ValueError, match="reach_spread_mm"):
        _cfg(reach_mm=4.0, reach_spread_mm=(-4.0, 0.0))
    with pytest.raises(ValueError, match="reach_spread_mm"):
        _cfg(reach_mm=4.0, reach_spread_mm=())


def test_the_sweep_stencil_is_every_cell_within_the_reach_of_the_swept_segment() -> None:
    st = sweep_stencil(3, 2.0, 4.0)   # rows -1..1 swept; 2 cells of reach
    assert st.shape == (7, 5)
    brute = np.array([[math.hypot(dx * 2.0, max(0, abs(dy) - 1) * 2.0) <= 4.0 for dx in range(-2, 3)]
                      for dy in range(-3, 4)])
    assert (st == brute).all()
    assert st[3, 0] and st[0, 2] and not st[0, 0]


def test_coverage_gain_counts_the_hidden_cells_one_sweep_would_reveal() -> None:
    obs = np.zeros((20, 20), dtype=bool)
    obs[:, :10] = True
    gain = coverage_gain(obs, 2.0, 4.0, 3)
    h = hidden(obs, 2.0, 4.0)
    st = sweep_stencil(3, 2.0, 4.0)
    for iy, ix in ((10, 15), (0, 19), (5, 12)):
        brute = sum(h[iy + dy, ix + dx] for dy in range(-3, 4) for dx in range(-2, 3)
                    if st[dy + 3, dx + 2] and 0 <= iy + dy < 20 and 0 <= ix + dx < 20)
        assert gain[iy, ix] == brute
    # 7 x 5 cells less the 12 whose distance to the segment is sqrt(4^2 + 2^2) or more (> 4 mm)
    assert gain[10, 5] == 0 and gain[10, 15] == 7 * 5 - 12


def test_detection_map_is_measured_where_measured_and_the_mean_only_near_it() -> None:
    measured = np.full((1, 6), np.nan)
    measured[0, 0] = 7.0
    mean = np.full((1, 6), 3.0)
    m = detection_map(measured, mean, 2.0, 4.0)
    assert m[0, 0] == 7.0 and m[0, 1] == 3.0 and m[0, 2] == 3.0   # 2 and 4 mm away: the mean
    assert np.isnan(m[0, 3:]).all()                                # farther: neither measured nor near


def test_the_blind_cells_give_the_background_where_the_resolving_sweeps_went_stiff() -> None:
    # an adaptive planner measured half its cells on a 1.3x inclusion: their median is no background, the cells of
    # the stiffness-blind sweeps are
    cfg = _cfg(reach_mm=40.0)
    measured = np.full((20, 20), 10.0)
    measured[:, 10:] = 13.0
    measured[:, 9] = 10.5
    counts = np.ones((20, 20), dtype=np.int64)
    fair = np.full((20, 20), np.nan)
    fair[:, :8] = 10.0   # the stiffness-blind sweeps saw the background
    _, det = detect_candidates(_belief(cfg), measured, counts, cfg, fair)
    assert det.baseline == pytest.approx(10.0, rel=1e-6)
    assert len(det.inclusions) == 1 and det.inclusions[0].x_mm > 20.0
    _, biased = detect_candidates(_belief(cfg), measured, counts, cfg)   # every measured cell: the 13s count
    assert biased.baseline > 10.5


def test_open_sides_are_the_unsampled_points_just_past_a_candidate() -> None:
    xs = np.arange(20, dtype=np.float64) * 2.0 + 1.0
    obs = np.zeros((20, 20), dtype=bool)
    c = Inclusion(x_mm=21.0, y_mm=21.0, radius_mm=3.0, contrast=2.0, peak=20.0, area_mm2=28.0, cells=7)
    sides = open_sides([c], obs, xs, xs, REGION, 2.0)
    assert sides == [(18.0, 21.0), (24.0, 21.0), (21.0, 18.0), (21.0, 24.0)]
    obs[10, 8] = True   # the cell at (17, 21): within one cell of the left side
    assert open_sides([c], obs, xs, xs, REGION, 2.0) == sides[1:]
    edge = Inclusion(x_mm=1.0, y_mm=21.0, radius_mm=1.0, contrast=2.0, peak=20.0, area_mm2=4.0, cells=1)
    assert (-1.0, 21.0) not in open_sides([edge], obs, xs, xs, REGION, 2.0)   # outside the region: no side


def test_a_sweep_through_a_candidates_middle_splits_two_inclusions_the_mean_bridged() -> None:
    cfg = _cfg(reach_mm=40.0, fill_mm=4.0)
    b = _belief(cfg)
    b.mean[8:13, 6:15] = 20.0   # the GP's smoothed guess: one blob over x 13..29 mm
    measured = np.full((20, 20), 10.0)
    measured[:, 6:15] = np.nan
    measured[8:13, 8] = measured[8:13, 12] = 20.0   # two sweeps, each through one inclusion
    counts = np.ones((20, 20), dtype=np.int64)
    found = detect_candidates(b, measured, counts, cfg, suspect=True)[1].inclusions
    assert len(found) == 1 and abs(found[0].x_mm - 21.0) < 0.5
    edge = decide(b, measured, counts, SEEDS, cfg).point   # its edges are what the planner samples
    assert edge is not None and abs(edge[0] - found[0].x_mm) > 1.0
    measured[:, 10] = 10.0   # the sweep there: soft
    assert len(detect_candidates(b, measured, counts, cfg, suspect=True)[1].inclusions) == 2


def test_decide_covers_until_nothing_can_hide_then_stops() -> None:
    cfg = _cfg(reach_mm=6.0, miss_probability=0.02)
    b = _belief(cfg)
    measured, counts = _unmeasured()
    probed = SEEDS
    d = decide(b, measured, counts, probed, cfg, last=(30.0, 30.0))
    # only the seed grid's four sweeps so far (3 cells each, no sample in them yet: they count all the same)
    assert not d.stop and d.blind and d.point is not None and d.miss == 0.4
    measured[:, ::6] = 10.0   # columns every 12 mm: every cell within 6 mm of one
    d = decide(b, measured, counts, probed, cfg)
    assert d.miss == 0.0 and d.stop and d.why.startswith("found")
    assert not decide(b, measured, counts, probed[:3], cfg).stop   # never before the seed grid is done
    measured[:, 18:] = np.nan   # the last 4 columns now 8..14 mm from the column at x = 25
    d = decide(b, measured, counts, probed, cfg)
    assert not d.stop and d.point is not None and d.point[0] > 30.0
    assert decide(b, measured, counts, probed * 15, cfg).why.startswith("probe budget")


def test_decide_takes_the_nearest_of_the_near_best_coverage_sweeps() -> None:
    cfg = _cfg(reach_mm=4.0, near_best=0.5)
    b = _belief(cfg)
    measured, counts = _unmeasured()
    probed = SEEDS
    near = decide(b, measured, counts, probed, cfg, last=(39.0, 39.0)).point
    far = decide(b, measured, counts, probed, cfg, last=(1.0, 1.0)).point
    assert near is not None and far is not None
    assert near[0] > 30 and near[1] > 30 and far[0] < 10 and far[1] < 10


def test_decide_samples_a_candidates_boundary_before_stopping() -> None:
    cfg = _cfg(reach_mm=40.0)   # coverage is no concern here
    b = _belief(cfg)
    measured = np.full((20, 20), 10.0)
    measured[8:13, 10] = 20.0            # one sweep crossed a stiff strip at x = 21 mm
    measured[:, 9] = measured[:, 11] = np.nan
    measured[:, 8] = measured[:, 12] = np.nan
    counts = np.ones((20, 20), dtype=np.int64)
    probed = SEEDS
    found = detect_candidates(b, measured, counts, cfg, suspect=True)[1].inclusions
    assert len(found) == 1
    d = decide(b, measured, counts, probed, cfg)
    assert not d.stop and not d.blind and d.point is not None
    assert d.point[1] == found[0].y_mm and abs(abs(d.point[0] - found[0].x_mm) - found[0].radius_mm) < 1e-9
    measured[:, 8:13] = np.where(np.isnan(measured[:, 8:13]), 10.0, measured[:, 8:13])   # both sides measured
    assert decide(b, measured, counts, probed, cfg).stop


def _column_rise(fraction: float) -> float:
    """The ratio a three-cell stretch of one measured column (its sides unmeasured) must rise by, on a map without
    noise (the detector's noise floor), to read ``fraction`` of the detector's threshold on the 40 mm region."""
    cfg = DetectorConfig()
    snr = fraction * threshold_for(400 * 4.0, cfg)
    return float(np.exp(snr * cfg.noise_floor_rel / np.sqrt(3.0)))


def test_a_weak_rise_is_a_suspect_to_resolve_but_not_a_detection() -> None:
    cfg = _cfg(reach_mm=40.0, suspect_false_alarm=0.9)   # suspects: what the detector reports at 0.9 per map
    b = _belief(cfg)
    measured = np.full((20, 20), 10.0)
    measured[8:13, 10] = 10.0 * _column_rise(0.75)   # 3/4 of the detector's threshold: over half of it
    measured[:, [8, 9, 11, 12]] = np.nan   # its sides unmeasured
    counts = np.ones((20, 20), dtype=np.int64)
    assert detect_candidates(b, measured, counts, cfg)[1].inclusions == []
    assert len(detect_candidates(b, measured, counts, cfg, suspect=True)[1].inclusions) == 1
    probed = SEEDS
    assert not decide(b, measured, counts, probed, cfg).stop
    # at the map's own false-alarm rate the suspects are the detections: the rise is none, nothing to resolve
    assert decide(b, measured, counts, probed, _cfg(reach_mm=40.0, suspect_false_alarm=0.003)).stop


def test_a_point_given_up_is_not_chosen_again() -> None:
    cfg = _cfg(reach_mm=4.0, near_best=1.0, miss_probability=0.0)   # cover to the last cell
    b = _belief(cfg)
    measured = np.full((20, 20), 10.0)
    measured[8:13, 8:13] = np.nan   # a 10 mm hole around (21, 21)
    counts = np.ones((20, 20), dtype=np.int64)
    seeds = SEEDS
    first = decide(b, measured, counts, seeds, cfg).point
    assert first is not None and first[0] == 21.0   # a sweep over the hole's middle column
    # the scanner refused it every time: the planner's probed list holds it, its cells unmeasured
    again = decide(b, measured, counts, [*seeds, first], cfg).point
    assert again is not None and math.dist(again, first) >= cfg.min_separation_mm


def test_tissue_only_a_refused_point_reaches_counts_as_covered() -> None:
    cfg = _cfg(reach_mm=2.0)
    b = _belief(cfg)
    measured = np.full((20, 20), 10.0)
    measured[8:13, 17:20] = np.nan   # by the edge, where the scanner's box ends
    counts = np.ones((20, 20), dtype=np.int64)
    seeds = SEEDS
    assert decide(b, measured, counts, seeds, cfg).miss > 0
    refused = (39.0, 21.0)
    d = decide(b, measured, counts, [*seeds, refused], cfg, given_up=[refused])
    assert d.miss == 0.0 and d.stop
    # a sweep made there whose samples landed elsewhere (none in those cells) covers them too: not asked for again
    assert decide(b, measured, counts, [*seeds, refused], cfg).stop


def test_unsensed_is_per_size_what_no_sweep_reached_and_averages_to_the_stop_rules_miss_probability() -> None:
    cfg = _cfg(reach_mm=4.0, radius_span_mm=2.0)   # reaches 4, 4.5, .., 6 mm
    xs, ys = cfg.grid()
    observed = np.zeros((20, 20), dtype=bool)
    observed[:, 0] = True   # one measured column at x = 1 mm: column i lies 2 i mm from it
    fractions, mask = unsensed(observed, xs, ys, [], cfg)
    assert [r for r, _ in fractions] == [4.0, 4.5, 5.0, 5.5, 6.0]
    # farther than 4 mm: columns 3.. (17 of 20); than 4.5 / 5 / 5.5: columns 3.. too; than 6: columns 4..
    assert [f for _, f in fractions] == [17 / 20, 17 / 20, 17 / 20, 17 / 20, 16 / 20]
    assert not mask[:, :3].any() and mask[:, 3:].all()   # the smallest's cells
    assert np.mean([f for _, f in fractions]) == pytest.approx(
        decide(_belief(cfg), np.where(observed, 10.0, np.nan), np.ones((20, 20), dtype=np.int64), [], cfg).miss)
    # a sweep made counts for the cells it crossed even with no sample in them (as the stop rule counts it)
    fractions, mask = unsensed(observed, xs, ys, [(39.0, 21.0)], cfg)
    # x = 39 mm is column 19, y 18..24 mm rows 9..11: within 4 mm of those cells are 3 x 3 of them, 2 more in rows
    # 8 and 12, 1 more in rows 7 and 13 (exactly 4 mm is sensed, 4.5 mm is not)
    assert not mask[9:12, 17:20].any() and not mask[8:13, 18:20].any() and not mask[7:14, 19].any()
    assert mask[8, 17] and mask[12, 17] and mask[7, 18] and mask[6, 19]
    assert fractions[0][1] == (17 * 20 - 15) / 400


def test_a_covering_sweep_stays_inside_the_region() -> None:
    cfg = _cfg(reach_mm=2.0, miss_probability=0.0)
    measured = np.full((20, 20), 10.0)
    measured[17:, :] = np.nan   # the top 6 mm unmeasured: its last row is hidden
    counts = np.ones((20, 20), dtype=np.int64)
    # from the top edge the nearest of the equal best sweeps would be centred on the last row, half outside
    p = decide(_belief(cfg), measured, counts, SEEDS, cfg, last=(21.0, 40.0)).point
    assert p is not None and p[1] + 0.5 * cfg.sweep_mm <= REGION[3]


def test_interior_gaps_ask_for_a_sweep_until_a_detection_is_measured_every_other_column() -> None:
    xs = np.arange(20, dtype=np.float64) * 2.0 + 1.0
    c = Inclusion(x_mm=21.0, y_mm=21.0, radius_mm=5.0, contrast=2.0, peak=20.0, area_mm2=78.0, cells=19)
    obs = np.zeros((20, 20), dtype=bool)
    obs[:, [6, 10, 14]] = True   # columns at x = 13, 21, 29 mm: 8 mm apart
    gaps = interior_gaps([c], obs, xs, xs, REGION, 2.0, 2.0, 3)
    assert gaps == [(17.0, 21.0)]   # in a gap between two columns, the sweep nearest the centre
    obs[:, [8, 12]] = True   # every other column over the disc: each cell within 2 mm of a measured one
    assert interior_gaps([c], obs, xs, xs, REGION, 2.0, 2.0, 3) == []
    assert interior_gaps([c], obs, xs, xs, REGION, 2.0, 1.0, 3) != []   # a finer gap wants every column
    corner = Inclusion(x_mm=1.0, y_mm=1.0, radius_mm=3.0, contrast=2.0, peak=20.0, area_mm2=28.0, cells=7)
    y = interior_gaps([corner], np.zeros((20, 20), dtype=bool), xs, xs, REGION, 2.0, 2.0, 3)[0][1]
    assert y == 3.0   # the sweep kept inside the region (3 cells: 6 mm)


def test_decide_measures_a_detections_disc_densely_before_stopping() -> None:
    cfg = _cfg(reach_mm=40.0, interior_gap_mm=2.0)   # coverage is no concern here
    b = _belief(cfg)
    measured = np.full((20, 20), 10.0)   # soft all round, its sides too
    measured[7:14, 8] = measured[7:14, 12] = 20.0   # two sweeps 8 mm apart (x = 17, 25 mm), both stiff
    measured[7:14, 9:12] = np.nan
    b.mean[7:14, 9:12] = 20.0   # the GP's guess between them: one blob
    counts = np.ones((20, 20), dtype=np.int64)
    found = detect_candidates(b, measured, counts, cfg)[1].inclusions
    assert len(found) == 1
    d = decide(b, measured, counts, SEEDS, cfg)
    assert not d.stop and not d.blind and d.point == (21.0, 21.0)   # the unmeasured column between them, middle
    assert decide(b, measured, counts, SEEDS, _cfg(reach_mm=40.0)).stop   # the rule off: its sides suffice
    measured[7:14, 10] = 10.0   # measured there: soft (two inclusions), every disc cell within 2 mm of a measured one
    assert decide(b, measured, counts, SEEDS, cfg).stop
    assert len(detect_candidates(b, measured, counts, cfg)[1].inclusions) == 2


def _near_miss(b: Belief, fraction: float, cfg: PlannerConfig, fair: npt.NDArray[np.float64]
               ) -> npt.NDArray[np.float64]:
    """Two sweeps 8 mm apart past a weak rise (and the GP's guess between them) whose significance reads ``fraction``
    of the detector's threshold (just under it)."""
    counts = np.ones((20, 20), dtype=np.int64)

    def rise(level: float) -> npt.NDArray[np.float64]:
        measured = np.full((20, 20), 10.0)
        measured[7:14, 8] = measured[7:14, 12] = level
        measured[7:14, 9:12] = np.nan
        b.mean[7:14, 9:12] = level
        return measured

    lo, hi = 0.0, 0.2   # the log-rise, bisected: the significance grows with it
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        det = detect_candidates(b, rise(10.0 * math.exp(mid)), counts, cfg, fair)[1]
        lo, hi = (mid, hi) if float(np.nanmax(det.significance)) < fraction * det.threshold_snr else (lo, mid)
    return rise(10.0 * math.exp(lo))


def test_a_near_miss_gets_its_disc_measured_at_its_own_gap_whether_or_not_detections_are() -> None:
    cfg = _cfg(reach_mm=40.0, interior_gap_mm=2.0, near_miss_false_alarm=0.04,
               near_miss_gap_mm=2.0)   # coverage: no concern
    b = _belief(cfg)
    fair = np.full((20, 20), 10.0)   # the blind cells: 10, no spread (the detector's noise floor)
    measured = _near_miss(b, 0.9, cfg, fair)   # 0.9 of the threshold's significance: 1 % false alarms per map
    counts = np.ones((20, 20), dtype=np.int64)
    detected = detect_candidates(b, measured, counts, cfg, fair)[1]
    assert detected.inclusions == []   # no detection
    d = decide(b, measured, counts, SEEDS, cfg, fair=fair)
    assert not d.stop and d.point == (21.0, 21.0) and d.kind == "measuring a near miss's disc"
    assert decide(b, measured, counts, SEEDS, replace(cfg, interior_gap_mm=0.0), fair=fair).point == d.point   # on its own
    assert decide(b, measured, counts, SEEDS, _cfg(reach_mm=40.0, interior_gap_mm=2.0), fair=fair).stop   # off
    assert decide(b, measured, counts, SEEDS, replace(cfg, near_miss_false_alarm=0.005), fair=fair).stop   # not close enough
    measured[7:14, 10] = measured[7, 8]   # its middle measured: still under the threshold, nothing left unmeasured
    assert detect_candidates(b, measured, counts, cfg, fair)[1].inclusions == []
    assert decide(b, measured, counts, SEEDS, cfg, fair=fair).stop
    finer = decide(b, measured, counts, SEEDS, replace(cfg, near_miss_gap_mm=1.5), fair=fair)
    assert not finer.stop and finer.point is not None and finer.point[0] in (19.0, 23.0)   # every column, as a raster
    assert decide(b, measured, counts, SEEDS, replace(cfg, near_miss_false_alarm=0.0, near_miss_gap_mm=1.5), fair=fair).stop
    suspects = detect_candidates(b, measured, counts, cfg, fair, suspect=True)[1].inclusions
    detected = detect_candidates(b, measured, counts, cfg, fair)[1]
    assert len(near_misses(suspects, detected, cfg)) == 1
    assert near_misses(suspects, replace(detected, inclusions=suspects), cfg) == []   # a detection's own halo
    assert near_misses(suspects, replace(detected, area_mm2=math.nan), cfg) == []   # no map to detect on yet
    for bad in ({"near_miss_false_alarm": -0.1}, {"near_miss_false_alarm": 1.0}, {"near_miss_gap_mm": 0.0}):
        with pytest.raises(ValueError, match="near_miss"):
            _cfg(**bad)


def test_the_planner_detects_with_the_law_of_the_probe_its_samples_come_from() -> None:
    """The camera planner's maps hold K_t (N/mm), whose noise is not the air-float's: its suspects and detections
    are judged by the camera probe's own false-alarm law, as the map aggregator's are; a probe without a measured
    law keeps the default's."""
    camera = detector_config(_cfg(model="multi_indenter"))
    assert camera.gumbel == FALSE_ALARM_LAWS["multi_indenter"] != DetectorConfig().gumbel
    assert detector_config(_cfg(model="multi_indenter"), suspect=True).gumbel == camera.gumbel
    assert detector_config(_cfg(model="")).gumbel == DetectorConfig().gumbel
    # the air-float planner's maps are partial: the law of its own blank maps, not a whole map's
    own = detector_config(_cfg(model="airfloat"))
    assert own.gumbel == PARTIAL_MAP_LAWS["airfloat"] != FALSE_ALARM_LAWS["airfloat"]
    assert detector_config(_cfg(model="airfloat"), suspect=True).gumbel == own.gumbel
    # a planner held to a probe budget leaves suspects unresolved on sparser maps: its own, heavier-tailed law (at
    # the same rate its threshold is higher); a probe with no budgeted law measured keeps its planner's
    budgeted = detector_config(_cfg(model="airfloat", budget_fraction=0.2))
    assert budgeted.gumbel == PARTIAL_MAP_LAWS["airfloat+budget"] != own.gumbel
    assert detector_config(_cfg(model="airfloat", budget_fraction=0.2), suspect=True).gumbel == budgeted.gumbel
    assert threshold_for(2080.0, budgeted) > threshold_for(2080.0, own) + 1.0
    assert detector_config(_cfg(model="multi_indenter", budget_fraction=0.2)).gumbel == camera.gumbel


def _detected_at(x: float, y: float, r: float) -> Detection:
    nan = np.full((20, 20), np.nan)
    inc = Inclusion(x, y, r, 3.0, 30.0, math.pi * r * r, 12, 20.0, 0.0)
    return Detection([inc], 10.0, 0.04, 4.4, nan, nan, np.zeros((20, 20), dtype=bool), nan, nan)


def test_off_halos_leaves_out_the_blind_cells_within_a_detections_radius_plus_the_halo() -> None:
    cfg = _cfg()
    xs, ys = cfg.grid()
    gx, gy = np.meshgrid(xs, ys)
    snap = MapSnapshot(stiffness=np.full((20, 20), 10.0), x_mm=xs, y_mm=ys, count=np.ones((20, 20), dtype=np.int64),
                       spread=np.zeros((20, 20)), resolution_mm=2.0)
    fair = np.ones((20, 20), dtype=bool)
    keep = off_halos(snap, fair, _detected_at(21.0, 21.0, 4.0), 4.0, 12)
    d = np.hypot(gx - 21.0, gy - 21.0)
    assert not keep[d <= 8.0].any() and keep[d > 8.0].all()   # the disc and 4 mm past its edge, no more
    assert np.count_nonzero(~keep) > np.count_nonzero(d <= 4.0)
    # too few cells would be left for the detector's background: the blind cells as they are
    assert off_halos(snap, fair, _detected_at(21.0, 21.0, 30.0), 4.0, 12).all()


def test_with_a_fair_halo_the_detector_estimates_again_without_the_detections_halos(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import models.adaptive_detect as ad

    seen: list[npt.NDArray[np.bool_]] = []
    real = ad.detect

    def spy(snap: MapSnapshot, dcfg: DetectorConfig, *, estimate_from: npt.NDArray[np.bool_],
            unmeasured: npt.NDArray[np.bool_]) -> Detection:
        seen.append(np.array(estimate_from, dtype=bool))
        return real(snap, dcfg, estimate_from=estimate_from, unmeasured=unmeasured)

    monkeypatch.setattr(ad, "detect", spy)
    measured = np.full((20, 20), 10.0) * np.exp(np.random.default_rng(3).normal(0.0, 0.03, (20, 20)))
    xs, ys = _cfg().grid()
    gx, gy = np.meshgrid(xs, ys)
    measured[np.hypot(gx - 21.0, gy - 21.0) <= 5.0] *= 3.0
    counts = np.ones((20, 20), dtype=np.int64)
    for halo, calls in ((0.0, 1), (4.0, 2)):
        seen.clear()
        cfg = _cfg(reach_mm=40.0, fair_halo_mm=halo)
        _, det = detect_candidates(_belief(cfg), measured, counts, cfg, measured)
        assert len(seen) == calls and det.inclusions
    inc = det.inclusions[0]   # the 3x disc, its halo left out of the second estimate; the rest of the cells kept
    near = np.hypot(gx - inc.x_mm, gy - inc.y_mm) <= inc.radius_mm + 4.0
    assert seen[0].all() and not seen[1][near].any() and np.count_nonzero(seen[1]) > 200


def test_region_gaps_ask_for_the_unmeasured_stretch_of_a_detections_region_past_its_disc() -> None:
    # a strong inclusion's halo joins a neighbour 16 mm away into one region above the threshold; its disc is
    # measured, the stretch between them is not: only a sweep there can show the dip that parts them
    cfg = _cfg()
    xs, ys = cfg.grid()
    gx, gy = np.meshgrid(xs, ys)
    sig = np.where((gx >= 8.0) & (gx <= 30.0) & (gy >= 8.0) & (gy <= 16.0), 10.0, 0.0)
    nan = np.full((20, 20), np.nan)
    inc = Inclusion(11.0, 11.0, 3.0, 3.0, 30.0, 28.0, 7, 10.0, 0.0)
    det = Detection([inc], 10.0, 0.04, 4.4, sig, nan, np.zeros((20, 20), dtype=bool), nan, nan)
    observed = ~((gx >= 18.0) & (gx <= 26.0))   # the columns between the two unmeasured
    assert interior_gaps([inc], observed, xs, ys, REGION, 2.0, 3.0, 3) == []
    masks = region_masks(det, xs, ys)
    assert len(masks) == 1 and masks[0][0].sum() == np.count_nonzero(sig > 4.4)
    points = mask_gaps(masks, observed, xs, ys, REGION, 2.0, 3.0, 3)
    assert len(points) == 1 and 20.0 <= points[0][0] <= 24.0 and 8.0 <= points[0][1] <= 16.0
    # a region measured to the gap asks for nothing; a detection outside any region (none above) neither
    assert mask_gaps(masks, np.ones((20, 20), dtype=bool), xs, ys, REGION, 2.0, 3.0, 3) == []
    assert region_masks(replace(det, significance=np.zeros((20, 20))), xs, ys) == []
