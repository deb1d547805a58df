"""bench/adaptive_staged.py's revealed maps: everything revealed is the full map; a bump never revealed is missed."""

from __future__ import annotations

import math
from dataclasses import replace
from types import ModuleType
from typing import Any

import numpy as np

from models.detector import Detection, DetectorConfig, detect, false_alarm_probability, with_law_of
from models.phantom import parse_phantom
from models.stiffness_map import MapSnapshot
from tests.procs import bench_module


def _bench() -> ModuleType:
    return bench_module("adaptive_staged")


def _run(b: ModuleType) -> tuple[Any, Detection]:
    """A 32 mm square map, 2 mm cells, 5 % cell noise, one weak bump (x1.15, r 3 mm) at (21, 17): between the
    lines of an every-6th-line lattice (x = 3, 15, 27), 6 mm from each."""
    ph = parse_phantom({"size_mm": [36, 36], "thickness_mm": 4, "youngs_modulus_kpa": 20.0,
                        "inclusions": [{"center_mm": [21, 17], "radius_mm": 3, "depth_mm": 2,
                                        "youngs_modulus_kpa": 40.0}]})
    x = y = 3.0 + 2.0 * np.arange(16)
    gx, gy = np.meshgrid(x, y)
    rng = np.random.default_rng(3)
    grid = 20.0 * np.exp(rng.normal(0.0, 0.05, gx.shape))
    grid[np.hypot(gx - 21, gy - 17) <= 3.0] *= 1.15
    snap = MapSnapshot(grid, x, y, np.full(gx.shape, 50), np.full(gx.shape, 1.0), 2.0)
    full = detect(snap, with_law_of(DetectorConfig(), "airfloat"))
    assert len(full.inclusions) == 1   # the planted bump, weak (a few σ) but over the map's bar
    return b.Run("synthetic-s0", "synthetic", ph, snap, "airfloat", (True,), {}), full


def test_revealing_everything_is_the_full_maps_detection_and_a_bump_never_revealed_is_missed() -> None:
    b = _bench()
    run, full = _run(b)
    every = np.ones(run.snap.stiffness.shape, dtype=bool)
    for nan in (True, False):   # blind cells NaN (the raster's map), or the planner's GP-filled map
        det, _ = b.detect_revealed(run, every, None, nan=nan)
        if nan:
            assert det.inclusions == full.inclusions
        else:   # the planner's maps have a false-alarm law of their own: the same bump, found, judged by that law
            (mine,), (theirs,) = det.inclusions, full.inclusions
            assert math.hypot(mine.x_mm - theirs.x_mm, mine.y_mm - theirs.y_mm) < 1.0
            partial = with_law_of(DetectorConfig(), "airfloat", partial=True)
            assert partial.gumbel != with_law_of(DetectorConfig(), "airfloat").gumbel
            assert mine.snr == theirs.snr
            assert mine.false_alarm == false_alarm_probability(mine.snr, det.area_mm2, partial) != theirs.false_alarm
        assert b.reveal_all(run, nan=nan) == (256.0, (True,), 0)
    # every 6th line, no stage: its cells never come within 4 mm of the bump's edge, so it is missed
    lat = b.lattice(run.snap, 6, 0)
    assert lat.sum(axis=0).tolist() == [16 if i in (0, 6, 12) else 0 for i in range(16)]
    assert b.run_scheme(run, b.Scheme(6, 0), nan=True) == (48.0, (False,), 0)
    # a stage that confirms nowhere (bar out of reach) reveals nothing more
    assert b.run_scheme(run, b.Scheme(6, 0, 99.0, 4.0, 3), nan=True)[:2] == (48.0, (False,))
    # the oracle's cells around the bump are its disc and 2 mm: revealed, it is found again
    cost, found, _ = b.oracle(run, 6, 0, nan=True)
    assert found == (True,) and 48.0 < cost < 256.0


def test_a_stage_reveals_the_available_cells_within_its_radius_of_a_hot_cell() -> None:
    b = _bench()
    hot = np.zeros((5, 5), dtype=bool)
    hot[2, 2] = True
    available = np.ones((5, 5), dtype=bool)
    available[2, 3] = False   # a gap the raster never measured stays blind
    out = b.grow(np.zeros((5, 5), dtype=bool), hot, available, 2.0, 2.0)
    assert out.sum() == 4 and out[2, 2] and out[1, 2] and out[3, 2] and out[2, 1] and not out[2, 3]


def test_a_false_positive_beside_a_true_inclusion_is_a_fragment_and_one_far_away_is_noise() -> None:
    b = _bench()
    run, full = _run(b)
    hit = full.inclusions[0]   # matched to the bump at (21, 17), r 3
    beside = replace(hit, x_mm=21.0 + 3.0 + 2.5)   # past the match's r + 1 mm, within its r + 4 mm
    far = replace(hit, x_mm=5.0, y_mm=29.0)
    assert b.fp_split(run, replace(full, inclusions=[hit])) == (0, 0)
    assert b.fp_split(run, replace(full, inclusions=[hit, beside, far])) == (1, 1)
