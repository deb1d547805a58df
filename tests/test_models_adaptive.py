"""models.adaptive: the GP belief, the level-set acquisition, the stop rule, and a closed loop on a synthetic map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.adaptive import (
    Belief,
    PlannerConfig,
    acquisition,
    ambiguous,
    fit_belief,
    footprint_cells,
    footprint_score,
    initial_design,
    level,
    next_probe,
    should_stop,
    unresolved,
)
from models.detector import detect
from models.stiffness_map import MapSnapshot

CFG = PlannerConfig((0.0, 0.0, 40.0, 40.0), initial=3, max_probes=40, stop_area_mm2=16.0)


def _belief(mean: list[float], std: list[float], lvl: float = 10.0) -> Belief:
    m = np.array([mean], dtype=float)
    return Belief(np.arange(len(mean), dtype=float), np.zeros(1), m, np.array([std], dtype=float), 5.0, lvl)


def test_acquisition_prefers_the_uncertain_cell_on_the_level_to_a_confident_or_far_one() -> None:
    b = _belief(mean=[10.0, 10.0, 30.0, 2.0], std=[3.0, 0.5, 3.0, 3.0])
    a = acquisition(b, beta=2.0)
    assert a.tolist()[0] == [6.0, 1.0, -14.0, -2.0]   # beta * sigma - |mu - h|
    assert int(np.argmax(a)) == 0


def test_ambiguous_cells_are_those_whose_band_straddles_the_level_by_more_than_epsilon() -> None:
    b = _belief(mean=[10.5, 15.0, 4.0, 9.0], std=[1.0, 1.0, 1.0, 0.4])
    assert ambiguous(b, beta=2.0).tolist()[0] == [True, False, False, False]
    # epsilon * baseline = 1.5: |10.5 - 10| + 1.5 = 2.0 is not < 2 sigma = 2.0
    assert ambiguous(b, beta=2.0, epsilon=0.3).tolist()[0] == [False, False, False, False]
    assert ambiguous(b, beta=2.0, epsilon=0.2).tolist()[0] == [True, False, False, False]


def test_implicit_level_is_a_fraction_to_the_top_floored_at_the_detector_threshold() -> None:
    implicit = PlannerConfig(CFG.region_mm, implicit_fraction=0.5)
    assert level(np.array([10.0, 30.0]), 10.0, implicit) == pytest.approx(20.0)    # halfway to the top
    assert level(np.array([10.0, 30.0]), 10.0, CFG) == pytest.approx(12.0)         # default: the floor
    assert level(np.array([10.0, 10.5]), 10.0, implicit) == pytest.approx(12.0)    # floor: 20 % over baseline


def test_stop_rule_waits_for_the_initial_design_then_stops_on_a_classified_map_or_the_budget() -> None:
    # band 2 sigma = 2; a cell is ambiguous when |mu - h| + epsilon * baseline (= 1) < 2
    flat = Belief(*CFG.grid(), np.full((20, 20), 10.0), np.full((20, 20), 1.0), 10.0, 12.0)
    unsure = Belief(*CFG.grid(), np.full((20, 20), 12.5), np.full((20, 20), 1.0), 10.0, 12.0)
    assert not should_stop(flat, CFG.initial**2 - 1, CFG)[0]
    assert should_stop(flat, CFG.initial**2, CFG)[0]              # nothing straddles the level: classified
    stop, why = should_stop(unsure, 20, CFG)
    assert not stop and "1600 mm^2" in why                        # every 2 mm cell ambiguous
    assert should_stop(unsure, CFG.max_probes, CFG) == (True, "probe budget spent (40 probes)")


def test_stop_rule_counts_area_against_the_tolerance() -> None:
    mean = np.full((20, 20), 10.0)
    mean[0, :3] = 12.0                                            # 3 cells of 4 mm^2 = 12 mm^2 < 16
    b = Belief(*CFG.grid(), mean, np.full((20, 20), 1.0), 10.0, 12.0)
    assert should_stop(b, 20, CFG)[0]
    mean[0, 3] = 12.0                                             # 16 mm^2: not below the tolerance
    assert not should_stop(Belief(*CFG.grid(), mean, b.std, 10.0, 12.0), 20, CFG)[0]


def test_initial_design_is_a_cell_centred_serpentine_grid() -> None:
    pts = initial_design(CFG)
    assert len(pts) == 9
    assert pts[:4] == [(20 / 3, 20 / 3), (20.0, 20 / 3), (100 / 3, 20 / 3), (100 / 3, 20.0)]


def test_next_probe_skips_points_already_probed() -> None:
    mean = np.full((20, 20), 10.0)
    mean[5, 5] = 12.0
    b = Belief(*CFG.grid(), mean, np.full((20, 20), 1.0), 10.0, 12.0)
    assert next_probe(b, [], CFG) == (11.0, 11.0)
    assert next_probe(b, [(11.0, 11.0)], CFG) != (11.0, 11.0)


def test_fit_belief_refuses_too_few_or_non_finite_observations() -> None:
    with pytest.raises(ValueError, match="need >= 2"):
        fit_belief([(1.0, 1.0)], [3.0], CFG)
    with pytest.raises(ValueError, match="need >= 2"):
        fit_belief([(1.0, 1.0), (2.0, 2.0)], [3.0, math.nan], CFG)


def _truth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A synthetic map: 10 kPa background, a 30 kPa disc of radius 5 mm at (28, 12)."""
    return np.where((x - 28.0) ** 2 + (y - 12.0) ** 2 <= 25.0, 30.0, 10.0)


def _closed_loop(noise_seed: int) -> tuple[list[tuple[float, float]], Belief]:
    """Probe a synthetic map with 6 mm sweeps (2 mm cells, along y), as the planner node does."""
    rng = np.random.default_rng(noise_seed)
    obs: dict[tuple[float, float], float] = {}
    probed: list[tuple[float, float]] = []
    queue = initial_design(CFG)
    belief = None
    while True:
        if not queue:
            assert belief is not None
            if should_stop(belief, len(probed), CFG)[0]:
                return probed, belief
            queue.append(next_probe(belief, probed, CFG))
        x, y = queue.pop(0)
        probed.append((x, y))
        cx = (math.floor(x / 2) + 0.5) * 2
        for cy in np.arange(math.floor((y - 3) / 2) * 2 + 1, y + 3, 2.0):
            if 0 < cy < 40:
                obs[(cx, float(cy))] = float(_truth(np.array(cx), np.array(cy)) + rng.normal(0, 0.5))
        if len(obs) >= 2:  # hyper-parameters optimised every 8 probes, as the node does
            reuse = belief.kernel if belief is not None and len(probed) % 8 else None
            belief = fit_belief(list(obs), list(obs.values()), CFG, kernel=reuse)


def test_closed_loop_finds_the_disc_and_classifies_it_with_fewer_probes_than_a_raster() -> None:
    """A 3 mm raster of this 40 mm square would sweep 13 lines x 40 mm = 87 six-mm probes; the planner, starting
    from a 3 x 3 grid that misses the disc, finds it within 2 mm on at most 40, and its belief puts the disc's
    centre above the level and the far corner below it. Deterministic for a noise seed."""
    probed, belief = _closed_loop(0)
    assert len(probed) <= CFG.max_probes
    snap = MapSnapshot(belief.mean, belief.x_mm, belief.y_mm, np.ones_like(belief.mean, dtype=np.int64),
                       belief.std, 2.0)
    found = detect(snap).inclusions
    assert len(found) == 1 and math.dist((found[0].x_mm, found[0].y_mm), (28.0, 12.0)) < 2.0
    assert belief.mean[6, 14] > belief.level > belief.mean[19, 0]   # (29, 13) inside, (1, 39) far away
    assert _closed_loop(0)[0] == probed


def test_belief_grid_has_the_map_grids_cells_when_the_region_is_not_a_whole_number_of_cells() -> None:
    from models.stiffness_map import StiffnessGrid

    cfg = PlannerConfig((2.0, 2.0, 45.0, 40.0))
    xs, ys = cfg.grid()
    g = StiffnessGrid(2.0, 2.0, 45.0, 40.0, 2.0).snapshot()
    assert np.array_equal(xs, g.x_mm) and np.array_equal(ys, g.y_mm)


SWEEP = PlannerConfig((0.0, 0.0, 40.0, 40.0), initial=3, sweep_mm=6.0)


def test_footprint_score_sums_the_ambiguity_a_sweep_would_cross_and_keeps_the_sweep_in_the_region() -> None:
    """A 6 mm sweep crosses 3 cells of 2 mm along y: the score of a centre is the sum of its 3 cells' excess
    ``beta * sigma - |mu - h| - epsilon * baseline`` (here 2 - 0 - 1 = 1 per ambiguous cell); the first and last
    rows cannot be centres (the sweep would leave the region)."""
    mean = np.full((20, 20), 10.0)
    mean[4:7, 3] = 12.0          # three ambiguous cells in one column: on the level, band 2 sigma = 2
    mean[10, 8] = 12.0           # one alone
    b = Belief(*SWEEP.grid(), mean, np.full((20, 20), 1.0), 10.0, 12.0)
    s = footprint_score(b, SWEEP)
    assert footprint_cells(SWEEP) == 3
    assert s[5, 3] == pytest.approx(3.0) and s[4, 3] == pytest.approx(2.0) and s[10, 8] == pytest.approx(1.0)
    assert np.isneginf(s[0]).all() and np.isneginf(s[-1]).all() and np.isfinite(s[1:-1]).all()
    assert next_probe(b, [], SWEEP) == (7.0, 11.0)   # the column of three, centred on its middle cell


def test_observed_cells_count_as_resolved_for_the_stop_rule_and_the_acquisition() -> None:
    mean = np.full((20, 20), 10.0)
    mean[0, :5] = 12.0                                   # 5 ambiguous cells = 20 mm^2 >= 16
    b = Belief(*CFG.grid(), mean, np.full((20, 20), 1.0), 10.0, 12.0)
    observed = np.zeros((20, 20), dtype=bool)
    assert not should_stop(b, 20, CFG, observed)[0]
    observed[0, :2] = True                               # two of them measured: 12 mm^2 left
    assert unresolved(b, CFG, observed)[0, :5].tolist() == [0.0, 0.0, 1.0, 1.0, 1.0]
    assert should_stop(b, 20, CFG, observed)[0]
    assert next_probe(b, [], CFG, observed) == (5.0, 1.0)   # the first unmeasured ambiguous cell


def test_seed_spacing_scales_the_initial_grid_with_the_region() -> None:
    assert len(initial_design(PlannerConfig((0.0, 0.0, 56.0, 56.0), seed_spacing_mm=14.0))) == 16
    assert len(initial_design(PlannerConfig((0.0, 0.0, 28.0, 56.0), seed_spacing_mm=14.0))) == 2 * 4
    assert len(initial_design(PlannerConfig((0.0, 0.0, 10.0, 10.0), seed_spacing_mm=14.0))) == 4   # at least 2 x 2
    small = PlannerConfig((0.0, 0.0, 28.0, 28.0), seed_spacing_mm=14.0)
    flat = Belief(*small.grid(), np.full((14, 14), 10.0), np.full((14, 14), 0.1), 10.0, 12.0)
    assert should_stop(flat, 4, small) == (True, "map classified: 0 mm^2 ambiguous < 16 mm^2 after 4 probes")
    assert not should_stop(flat, 3, small)[0]
