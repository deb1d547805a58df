"""models.adaptive_route: the probe's route through a batch of chosen points, the coarse pass and its spacing rule;
and the planner's suspects confirmed, dismissed and measured again by the map detector's own rule (issue 41)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from models.adaptive import PlannerConfig
from models.adaptive_cover import distance_to_measured, lattice_cells, miss_probability
from models.adaptive_detect import decide, detect_candidates, near_misses, swept_cells
from models.adaptive_route import coarse_pass, coarse_spacing, order_route, route_length
from models.detector import DetectorConfig, detect, false_alarm_probability
from tests.test_models_adaptive_detect import SEEDS, _belief, _cfg, _near_miss


def _nearest_neighbour_length(points: list[tuple[float, float]], start: tuple[float, float]) -> float:
    left, here, total = list(points), start, 0.0
    while left:
        nxt = min(left, key=lambda p: math.dist(here, p))
        total += math.dist(here, nxt)
        left.remove(nxt)
        here = nxt
    return total


def test_the_route_visits_every_point_once_and_is_shorter_than_the_order_given_and_nearest_neighbour_alone() -> None:
    rng = random.Random(41)
    pts = [(round(rng.uniform(0, 50), 1), round(rng.uniform(0, 50), 1)) for _ in range(25)]
    start = (0.0, 0.0)
    route = order_route(pts, start)
    assert sorted(route) == sorted(pts)   # each point once, none added
    given, greedy = route_length(pts, start), _nearest_neighbour_length(pts, start)
    assert route_length(route, start) < greedy < given   # 2-opt improves on the nearest neighbour's tour here
    assert order_route(pts, start) == route   # deterministic


def test_points_on_a_line_are_visited_end_to_end_and_a_route_starts_at_the_nearest() -> None:
    pts = [(float(x), 0.0) for x in (30, 10, 50, 0, 20, 40)]
    assert order_route(pts, (-5.0, 0.0)) == [(0.0, 0.0), (10.0, 0.0), (20.0, 0.0), (30.0, 0.0), (40.0, 0.0), (50.0, 0.0)]
    assert order_route(pts, (60.0, 0.0))[0] == (50.0, 0.0)
    assert order_route([], None) == [] and order_route([(1.0, 2.0)], None) == [(1.0, 2.0)]


def test_the_coarse_spacing_rule_leaves_nothing_of_the_smallest_reach_unswept_inside_the_lattice() -> None:
    """Columns twice the smallest inclusion's reach apart and a sweep every twice its length along them, staggered:
    every cell of the lattice's interior lies within about that reach of a swept cell (4.5 mm for 4: the corners of
    a column's gaps); one cell more between the columns leaves cells 5.7 mm from every sweep."""
    reach, sweep, cell = 4.0, 6.0, 2.0
    assert coarse_spacing(reach, sweep) == (8.0, 12.0)
    column, period = coarse_spacing(reach, sweep)
    k = round(sweep / cell)

    def farthest(column_cells: int) -> float:
        shape = (60, 60)   # 120 mm square: an interior far from the lattice's edges
        swept = np.zeros(shape, dtype=bool)
        for iy, ix in lattice_cells(shape, k, column_cells, round(period / cell), 0, 0):
            swept[max(0, iy - k // 2):iy - k // 2 + k, ix] = True
        return float(distance_to_measured(swept, cell)[15:45, 15:45].max())

    assert farthest(round(column / cell)) <= 1.15 * reach
    assert farthest(round(column / cell) + 1) > 1.4 * reach
    with pytest.raises(ValueError, match="reach_mm"):
        coarse_spacing(0.0, sweep)


def test_the_coarse_pass_covers_the_region_to_the_tolerance_each_sweep_once_along_a_short_route() -> None:
    cfg = PlannerConfig((6.0, 6.0, 59.0, 51.9), sweep_mm=6.0, cover_column_mm=8.0, cover_period_mm=12.0)
    points = coarse_pass(cfg)
    assert points and len(set(points)) == len(points) <= cfg.max_probes
    xs, ys = cfg.grid()
    covered = swept_cells(np.zeros((len(ys), len(xs)), dtype=bool), xs, ys, points, cfg)
    assert miss_probability(covered, cfg.resolution_mm, cfg.reaches()) < cfg.miss_probability
    # the route is no longer than the lattice's own serpentine order through the same points
    assert route_length(points) <= route_length(sorted(points, key=lambda p: (p[0], p[1])))
    assert coarse_pass(PlannerConfig((0.0, 0.0, 40.0, 40.0), sweep_mm=0.0)) == []   # presses: no lattice
    # a region that is no whole number of cells: its last column's sweeps on its edge, not a cell centre past it
    odd = PlannerConfig((6.0, 6.0, 38.9, 47.9), sweep_mm=6.0, cover_column_mm=8.0, cover_period_mm=14.0)
    assert odd.grid()[0][-1] > 38.9 and all(6.0 <= x <= 38.9 for x, _ in coarse_pass(odd))


def test_suspects_are_what_the_map_detector_reports_at_the_looser_false_alarm_rate() -> None:
    cfg = _cfg(reach_mm=40.0, suspect_false_alarm=0.4)
    b = _belief(cfg)
    fair = np.full((20, 20), 10.0)
    measured = _near_miss(b, 0.75, cfg, fair)   # 3/4 of the map's threshold: under the map's bar, over the looser one
    counts = np.ones((20, 20), dtype=np.int64)
    snap, detected = detect_candidates(b, measured, counts, cfg, fair)
    _, suspects = detect_candidates(b, measured, counts, cfg, fair, suspect=True)
    loose = detect(snap, DetectorConfig(false_alarm_per_map=0.4), estimate_from=np.isfinite(fair))
    assert detected.inclusions == [] and len(suspects.inclusions) == 1
    assert suspects.inclusions == loose.inclusions and suspects.threshold_snr == loose.threshold_snr
    # confirmed by the map's own rule when its bar is the suspects': a detection, nothing left to call near
    assert decide(b, measured, counts, SEEDS, _cfg(reach_mm=40.0, suspect_false_alarm=0.003)).stop


def test_a_near_miss_is_decided_by_its_false_alarm_probability_under_the_detectors_law() -> None:
    cfg = _cfg(reach_mm=40.0, near_miss_false_alarm=0.04)
    b = _belief(cfg)
    fair = np.full((20, 20), 10.0)
    measured = _near_miss(b, 0.85, cfg, fair)
    counts = np.ones((20, 20), dtype=np.int64)
    _, detected = detect_candidates(b, measured, counts, cfg, fair)
    suspects = detect_candidates(b, measured, counts, cfg, fair, suspect=True)[1].inclusions
    assert detected.inclusions == [] and len(suspects) == 1
    p = false_alarm_probability(suspects[0].snr, detected.area_mm2, DetectorConfig())
    assert 0.003 < p < 0.04   # a blank map peaks this high between 0.3 % and 4 % of the time
    from dataclasses import replace
    assert len(near_misses(suspects, detected, replace(cfg, near_miss_false_alarm=p * 1.01))) == 1
    assert near_misses(suspects, detected, replace(cfg, near_miss_false_alarm=p * 0.99)) == []


def test_a_press_chosen_in_the_grids_partial_last_cell_is_made_on_the_regions_edge() -> None:
    """The camera's presses: the most ambiguous cell is the last column, whose centre lies past the region; the
    press is made on the region's edge, where the probe's tips are still on the specimen."""
    from models.adaptive import Belief, next_probe

    cfg = PlannerConfig((0.0, 0.0, 16.5, 16.5), resolution_mm=4.0)   # cells centred at 2 ... 18: the last past 16.5
    xs, ys = cfg.grid()
    std = np.full((len(ys), len(xs)), 0.01)
    std[:, -1] = 5.0   # only the last column is uncertain
    b = Belief(xs, ys, np.full(std.shape, 10.0), std, 10.0, 12.0)
    x, y = next_probe(b, [], cfg)
    assert xs[-1] > 16.5 and x == 16.5 and 0.0 <= y <= 16.5
    # once made (or given up), the same point is not chosen again: the check is where the probe went
    again = next_probe(b, [(x, y)], cfg)
    assert again != (x, y) and again[0] <= 16.5
