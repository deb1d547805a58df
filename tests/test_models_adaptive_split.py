"""models.adaptive_split: a detection is split where its measured cells show two maxima with a measured dip between
them, never on a dip only the GP's guess shows, never on one inclusion's noise."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest

from models.adaptive import Belief, PlannerConfig
from models.adaptive_detect import detect_candidates
from models.adaptive_split import bridge_levels, peak_parts, split_detections
from models.detector import Detection, DetectorConfig, detect
from models.stiffness_map import MapSnapshot

BASE, SIGMA = 20.0, 1.0
NOISE = SIGMA / BASE
"""The maps here are smooth; their detections are given this relative noise, the scale a prominence counts in."""
CFG = DetectorConfig(split_snr=math.inf)   # the detector's own cut off: what is tested here is the planner's
YS, XS = np.mgrid[0:20, 0:20].astype(np.float64) * 2.0 + 1.0   # 2 mm cells, centres 1..39 mm


def _bump(x: float, y: float, peak: float, width: float) -> npt.NDArray[np.float64]:
    return np.asarray(peak * np.exp(-((XS - x) ** 2 + (YS - y) ** 2) / (2 * width**2)), dtype=np.float64)


def _snap(grid: npt.NDArray[np.float64]) -> MapSnapshot:
    return MapSnapshot(grid, XS[0], YS[:, 0], np.ones(grid.shape, dtype=np.int64), np.zeros(grid.shape), 2.0)


def _detect(snap: MapSnapshot) -> Detection:
    return replace(detect(snap, CFG), noise_rel=NOISE)


def _split(grid: npt.NDArray[np.float64], measured: npt.NDArray[np.bool_], k: float = 2.0) -> int:
    snap = _snap(grid)
    return len(split_detections(_detect(snap), snap, measured, CFG, prominence_k=k))


def _plateau() -> npt.NDArray[np.float64]:
    grid = BASE + _bump(21.0, 19.0, 40.0, 4.5)   # one 3x inclusion
    grid[8, 9:12], grid[9, 9:12], grid[10, 10] = 58.0, 55.5, 58.5   # a ridge of the plateau and a dip 2.5 under it
    return grid


def _pair() -> npt.NDArray[np.float64]:
    # two inclusions one above the other, 10 mm apart: peaks 34, the dip between them 27 (over the threshold, 24)
    return BASE + _bump(21.0, 15.0, 14.0, 3.5) + _bump(21.0, 25.0, 14.0, 3.5)


def test_two_maxima_with_a_measured_dip_between_are_two_inclusions() -> None:
    grid = _pair()
    snap = _snap(grid)
    det = _detect(snap)
    found = det.inclusions
    assert len(found) == 1   # the matched filter joins the two halos: one blob
    dip = float(grid[9:11, 10].min())
    assert dip < 34.0 - 2 * SIGMA
    split = split_detections(det, snap, np.ones(grid.shape, dtype=bool), CFG, prominence_k=2.0)
    assert len(split) == 2
    lo, hi = sorted(i.y_mm for i in split)   # each part's centroid by its own peak (the other's tail pulls it in)
    assert abs(lo - 15.0) < 2.0 and abs(hi - 25.0) < 2.0 and all(abs(i.x_mm - 21.0) < 0.5 for i in split)
    # the dip stands 6-7 noise scales under the peaks: asking for 8 leaves the blob whole
    assert _split(grid, np.ones(grid.shape, dtype=bool), k=8.0) == 1


def test_one_inclusions_noisy_dome_is_one_inclusion() -> None:
    rng = np.random.default_rng(3)
    noise_maxima = 0
    for _ in range(20):   # a wide dome and its cells' noise (the baseline's scale): one maximum that stands out
        grid = BASE + _bump(20.0, 20.0, 14.0, 5.0) + SIGMA * rng.standard_normal((20, 20))
        assert _split(grid, np.ones(grid.shape, dtype=bool)) == 1
        region = grid > 24.0   # the noise makes maxima of its own: a prominence of zero would cut the dome at each
        noise_maxima += len(peak_parts(grid, region, region, prominence=0.0)) - 1
    assert noise_maxima >= 5


def test_a_dip_only_the_unmeasured_cells_show_is_no_evidence() -> None:
    grid = _pair()
    measured = np.zeros(grid.shape, dtype=bool)
    measured[:, [8, 12]] = True   # sweeps at x = 17 and 25 mm: the inclusions' flanks, the dip's row unmeasured
    measured[5:9, 10] = measured[12:16, 10] = True   # the middle column only on the peaks
    assert _split(grid, measured) == 1
    measured[9:12, 10] = True   # the middle column across the dip too
    assert _split(grid, measured) == 2


def test_an_unmeasured_cell_bridges_at_its_stiffest_measured_neighbour() -> None:
    grid = np.array([[1.0, 5.0, 2.0], [3.0, 9.0, 4.0], [7.0, 6.0, 8.0]])
    measured = np.array([[True, False, True], [True, False, False], [False, False, False]])
    lv = bridge_levels(grid, measured)
    assert lv[0, 0] == 1.0 and lv[0, 2] == 2.0   # measured: its own value
    assert lv[0, 1] == 2.0 and lv[1, 1] == 3.0 and lv[1, 2] == 2.0   # its stiffest measured side neighbour
    assert lv[2, 0] == 3.0 and lv[2, 2] == np.inf   # only a corner (1.0 at [0, 0] for [1, 1]) or none: no level


def test_peak_parts_cut_at_the_dip_and_merge_a_shallow_one() -> None:
    level = np.array([[9.0, 8.0, 5.0, 8.5, 9.5]])
    region = np.ones(level.shape, dtype=bool)
    parts = peak_parts(level, region, region, prominence=3.0)
    assert [p.nonzero()[1].tolist() for p in parts] == [[0, 1], [2, 3, 4]]   # the dip joins the higher peak
    assert len(peak_parts(level, region, region, prominence=4.5)) == 1   # the lower peak stands 4 over the dip
    assert len(peak_parts(level, region, region & (np.arange(5) != 0), prominence=3.0)) == 2
    only_one = region & (np.arange(5) >= 3)   # the left peak is not measured: no second maximum
    assert len(peak_parts(level, region, only_one, prominence=3.0)) == 1


def test_the_planner_splits_its_detections_but_not_its_suspects() -> None:
    region = (0.0, 0.0, 40.0, 40.0)
    cfg = PlannerConfig(region, sweep_mm=6.0, seed_spacing_mm=40.0)
    xs, ys = cfg.grid()
    grid = _pair()
    b = Belief(xs, ys, grid.copy(), np.full(grid.shape, 0.5), BASE, BASE * 1.2)
    counts = np.ones(grid.shape, dtype=np.int64)
    fair = np.full(grid.shape, np.nan)
    fair[0:2, :] = BASE + SIGMA * np.tile([-1.0, 1.0], 20).reshape(2, 20)   # blind cells: median 20, scale ~1
    assert len(detect_candidates(b, grid, counts, cfg, fair)[1].inclusions) == 2
    off = PlannerConfig(region, sweep_mm=6.0, seed_spacing_mm=40.0, split_prominence=0.0)
    # the suspects go through the detector alone, never the planner's split (it would only add sides to sample)
    suspects = detect_candidates(b, grid, counts, cfg, fair, suspect=True)[1].inclusions
    assert suspects == detect_candidates(b, grid, counts, off, fair, suspect=True)[1].inclusions
    plateau = _plateau()
    b = Belief(xs, ys, plateau.copy(), np.full(grid.shape, 0.5), BASE, BASE * 1.2)
    # a stiff plateau scattering 3x as much as healthy tissue is cut too: the known cost of an absolute prominence
    assert len(detect_candidates(b, plateau, counts, cfg, fair)[1].inclusions) == 2


def test_a_maximum_only_the_gp_shows_is_no_second_inclusion() -> None:
    grid = _pair()
    measured = np.zeros(grid.shape, dtype=bool)
    measured[:11, :] = True   # the lower inclusion and the dip measured; the upper one only the GP's guess
    assert _split(grid, measured) == 1
    measured[11:, :] = True
    assert _split(grid, measured) == 2


def test_a_one_cell_maximum_leaves_its_region_whole() -> None:
    grid = BASE + _bump(21.0, 15.0, 14.0, 3.5)
    grid[11, 10] = 30.0   # one stiff cell (a spike) 2 mm past the flank, joined to the blob by cells over the threshold
    grid[10, 10] = 25.0
    snap = _snap(grid)
    det = _detect(snap)
    assert len(det.inclusions) == 1
    split = split_detections(det, snap, np.ones(grid.shape, dtype=bool), CFG, prominence_k=1.5)
    assert split == det.inclusions   # not a blob less its spike's cell


def test_a_negative_prominence_is_refused() -> None:
    with pytest.raises(ValueError, match="split_prominence"):
        PlannerConfig((0.0, 0.0, 40.0, 40.0), split_prominence=-1.0)
