"""models.adaptive_budget: a probe budget that is a fraction of the raster's over the region, and the most likely
candidates confirmed first when it binds (models.adaptive_detect.decide)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from models.adaptive import Belief, PlannerConfig
from models.adaptive_budget import most_likely, raster_equivalents, with_budget
from models.adaptive_detect import decide, detect_candidates

REGION = (0.0, 0.0, 40.0, 40.0)   # 20 x 20 cells of 2 mm
SEEDS = [(10.0, 10.0), (30.0, 10.0), (10.0, 30.0), (30.0, 30.0)]


def _cfg(**kw: Any) -> PlannerConfig:
    kw = {"radius_span_mm": 0.0, "interior_gap_mm": 0.0, "cover_column_mm": 0.0, "near_miss_false_alarm": 0.0, **kw}
    return PlannerConfig(REGION, sweep_mm=6.0, seed_spacing_mm=40.0, **kw)


def test_the_raster_equivalents_are_its_lines_swept_length_in_sweeps() -> None:
    # 41 mm wide: lines at 0, 3, ..., 39 (14 of them), each 30 mm long, in 6 mm sweeps
    assert raster_equivalents((0.0, 0.0, 41.0, 30.0), 6.0, 3.0) == 14 * 30 / 6
    assert raster_equivalents((5.0, 5.0, 44.0, 35.0), 6.0, 3.0) == 14 * 30 / 6   # 39 mm: a line on both edges
    with pytest.raises(ValueError, match="line_mm"):
        raster_equivalents(REGION, 6.0, 0.0)


def test_the_budget_lowers_max_probes_to_its_fraction_of_the_raster_and_never_raises_it() -> None:
    cfg = PlannerConfig((0.0, 0.0, 41.0, 30.0), sweep_mm=6.0, budget_fraction=0.2)
    assert with_budget(cfg).max_probes == 14   # 0.2 x 70
    assert with_budget(replace(cfg, budget_fraction=0.25)).max_probes == 17   # 17.5, rounded down
    assert with_budget(replace(cfg, max_probes=10)).max_probes == 10
    assert with_budget(replace(cfg, budget_fraction=0.0)).max_probes == 60   # off
    assert with_budget(replace(cfg, sweep_mm=0.0)).max_probes == 60   # presses: no swept length to compare
    bads: list[dict[str, Any]] = [{"budget_fraction": -0.1}, {"raster_line_mm": 0.0}]
    for bad in bads:
        with pytest.raises(ValueError, match="budget_fraction"):
            PlannerConfig(REGION, **bad)


def test_most_likely_takes_whole_levels_smallest_false_alarm_first_until_the_budget_is_covered() -> None:
    prio = {(1.0, 1.0): 0.3, (2.0, 2.0): 0.001, (3.0, 3.0): 0.3, (4.0, 4.0): 0.02, (5.0, 5.0): 0.001}
    assert most_likely(prio, 5) == list(prio)   # all fit
    assert most_likely(prio, 1) == [(2.0, 2.0), (5.0, 5.0)]   # the whole first level
    assert most_likely(prio, 3) == [(2.0, 2.0), (5.0, 5.0), (4.0, 4.0)]
    assert most_likely(prio, 4) == [(2.0, 2.0), (5.0, 5.0), (4.0, 4.0), (1.0, 1.0), (3.0, 3.0)]


def _two_blobs(b: Belief, cfg: PlannerConfig, weak: float) -> npt.NDArray[np.float64]:
    """A strong detection between two stiff sweeps at x = 17 and 25 mm, and a weak one between two at x = 29 and
    37 mm lower down whose significance reads ``weak`` times the detector's threshold (the GP's guess between each
    pair: their level); soft tissue round them, measured."""
    counts = np.ones((20, 20), dtype=np.int64)

    def blobs(level: float) -> npt.NDArray[np.float64]:
        measured = np.full((20, 20), 10.0)
        measured[9:16, 8] = measured[9:16, 12] = 20.0
        measured[9:16, 9:12] = np.nan
        b.mean[9:16, 9:12] = 20.0
        measured[0:7, 14] = measured[0:7, 18] = level
        measured[0:7, 15:18] = np.nan
        b.mean[0:7, 15:18] = level
        return measured

    lo, hi = 0.0, 0.5   # the weak one's log-rise, bisected on its significance at its centre
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        det = detect_candidates(b, blobs(10.0 * np.exp(mid)), counts, cfg)[1]
        lo, hi = (mid, hi) if float(det.significance[3, 16]) < weak * det.threshold_snr else (lo, mid)
    return blobs(10.0 * np.exp(hi))


def test_a_binding_budget_confirms_the_likelier_detection_before_a_nearer_weaker_one() -> None:
    cfg = _cfg(reach_mm=40.0, interior_gap_mm=2.0)   # coverage is no concern here
    xs, ys = cfg.grid()
    b = Belief(xs, ys, np.full((20, 20), 10.0), np.full((20, 20), 0.5), 10.0, 12.0)
    measured = _two_blobs(b, cfg, 1.3)
    counts = np.ones((20, 20), dtype=np.int64)
    found = detect_candidates(b, measured, counts, cfg)[1].inclusions
    assert len(found) == 2 and max(c.snr for c in found) > 2 * min(c.snr for c in found)
    last = (33.0, 1.0)   # the probe beside the weak one
    free = decide(b, measured, counts, SEEDS, cfg, last)
    assert not free.stop and free.point is not None and free.point[0] == 33.0   # no budget: the nearest first
    one_left = replace(cfg, budget_fraction=0.2, max_probes=len(SEEDS) + 1)
    tight = decide(b, measured, counts, SEEDS, one_left, last)
    assert not tight.stop and tight.point is not None and tight.point[0] == 21.0   # the likelier one's disc
    assert tight.kind == "measuring a detection's disc"
    roomy = replace(one_left, max_probes=60)   # the budget does not bind: the route's order as without it
    assert decide(b, measured, counts, SEEDS, roomy, last).point == free.point


def test_a_budget_to_spend_covers_past_the_tolerance_until_it_is_spent_or_nothing_can_hide() -> None:
    cfg = _cfg(reach_mm=4.0, miss_probability=0.5)   # a loose tolerance: a corner left unmeasured is within it
    xs, ys = cfg.grid()
    b = Belief(xs, ys, np.full((20, 20), 10.0), np.full((20, 20), 0.5), 10.0, 12.0)
    measured = np.full((20, 20), 10.0)   # soft tissue, nothing to resolve
    measured[12:, 12:] = np.nan   # but a 16 mm corner never measured
    counts = np.ones((20, 20), dtype=np.int64)
    assert decide(b, measured, counts, SEEDS, cfg).stop   # within the tolerance: the rule stops
    spend = replace(cfg, budget_fraction=0.2, spend_budget=True, max_probes=len(SEEDS) + 1)
    d = decide(b, measured, counts, SEEDS, spend)
    assert not d.stop and d.blind and d.point is not None and d.point[0] > 24.0 and d.point[1] > 24.0   # the corner
    assert decide(b, measured, counts, SEEDS, replace(spend, spend_budget=False)).stop
    assert decide(b, measured, counts, SEEDS, replace(spend, budget_fraction=0.0)).stop   # no budget, nothing to spend
    assert decide(b, measured, counts, [*SEEDS, (1.0, 1.0)], spend).stop   # spent
    measured[12:, 12:] = 10.0
    assert decide(b, measured, counts, SEEDS, spend).stop   # nothing of interest could hide anywhere
