"""models.detector (issue 37): a matched filter against a robust background, a threshold from a false-alarm rate."""

from __future__ import annotations

import functools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from models.background import raised_above_plane
from models.detector import (
    DetectorConfig,
    detect,
    false_alarm_probability,
    fit_false_alarm_law,
    peak_significance,
    threshold_for,
    with_law_of,
)
from models.stiffness_map import MapSnapshot, StiffnessGrid, to_inclusions_json

BASE = 26.4  # kPa, the papers' background silicone
CELL = 2.0
XS = np.arange(30) * CELL + 1.0   # a 60 x 60 mm map of 2 mm cells


def _field(blobs: list[tuple[float, float, float, float]], *, noise: float, seed: int,
           dome: float = 0.0) -> npt.NDArray[np.float64]:
    """A map of the background (optionally a dome: ``dome`` relative rise at the centre) with cylindrical
    inclusions (cx, cy, radius, ratio) and relative per-cell noise, smoothed over a cell's neighbours as a probe's
    footprint smooths it."""
    rng = np.random.default_rng(seed)
    gy, gx = np.meshgrid(XS, XS, indexing="ij")
    v = BASE * (1 + dome * (1 - ((gx - 30) ** 2 + (gy - 30) ** 2) / 900.0))
    for cx, cy, r, ratio in blobs:
        v = np.where(np.hypot(gx - cx, gy - cy) <= r, v * ratio, v)
    return np.asarray(v * np.exp(noise * rng.standard_normal(v.shape)), dtype=np.float64)


def _snap(grid: npt.NDArray[np.float64]) -> MapSnapshot:
    return MapSnapshot(grid, XS, XS, np.ones(grid.shape, dtype=np.int64), np.zeros(grid.shape), CELL)


@functools.cache
def _calibrated() -> DetectorConfig:
    """The detector calibrated as bench/detector_calibration.py calibrates it, on these synthetic maps' blanks (their
    noise is white, unlike the probe's: the shipped law is the probe's): forty draws, flat and domed. One fit: the
    candidates the law is measured with do not depend on the threshold it sets."""
    dets = [detect(_snap(_field([], noise=0.05, seed=s, dome=d))) for s in range(100, 120) for d in (0.0, 0.3)]
    loc, scale = fit_false_alarm_law([peak_significance(d) for d in dets], [d.area_mm2 for d in dets], 3600.0)
    return replace(DetectorConfig(), gumbel=(loc, scale, 3600.0))


def test_blobs_are_found_where_they_are_with_their_significance() -> None:
    blobs = [(15.0, 15.0, 5.0, 2.0), (45.0, 20.0, 3.0, 1.6), (30.0, 45.0, 4.0, 1.3)]
    det = detect(_snap(_field(blobs, noise=0.04, seed=1)), _calibrated())
    assert len(det.inclusions) == 3
    for cx, cy, r, ratio in blobs:
        best = min(det.inclusions, key=lambda i: math.hypot(i.x_mm - cx, i.y_mm - cy))
        assert math.hypot(best.x_mm - cx, best.y_mm - cy) <= 1.0
        assert best.radius_mm == pytest.approx(r, abs=1.5)
        assert best.contrast == pytest.approx(ratio, rel=0.2)
        assert best.snr > det.threshold_snr and 0 < best.false_alarm < 1e-3
    assert [i.snr for i in det.inclusions] == sorted((i.snr for i in det.inclusions), reverse=True)
    assert det.noise_rel == pytest.approx(0.04, rel=0.25)
    assert det.baseline == pytest.approx(BASE, rel=0.02)


def test_blank_maps_give_the_stated_false_alarm_rate() -> None:
    """Flat or domed (the background surface follows a dome's 30 % rise), forty fresh noise draws (not the forty the
    law was fitted on): at the default 0.3 % per map about 0.1 maps with a detection are expected, three or more
    has a chance under 0.1 %; at 50 % per map about 20, and 10-30 covers it (binomial, 99.9 %): the threshold
    follows the stated rate both ways, not merely "high enough"."""
    cfg = _calibrated()
    maps = [_snap(_field([], noise=0.05, seed=s, dome=dome)) for s in range(20) for dome in (0.0, 0.3)]
    assert sum(bool(detect(m, cfg).inclusions) for m in maps) <= 2
    loose = replace(cfg, false_alarm_per_map=0.5)
    assert 10 <= sum(bool(detect(m, loose).inclusions) for m in maps) <= 30


def test_candidates_do_not_raise_the_background_or_the_threshold() -> None:
    """A third of the map on stiff inclusions: whole-map statistics would take their cells for background (median
    and spread raised, a weak inclusion under the threshold); the background from the cells that are no candidates
    finds the weak one and keeps the baseline and noise of the healthy tissue."""
    blobs = [(x, y, 6.5, 2.5) for x in (12.0, 48.0) for y in (12.0, 48.0)] + [(30.0, 12.0, 6.5, 2.5),
                                                                              (30.0, 48.0, 6.5, 2.5)]
    weak = (30.0, 30.0, 3.5, 1.10)
    grid = _field([*blobs, weak], noise=0.03, seed=4)
    det = detect(_snap(grid), _calibrated())
    assert det.baseline == pytest.approx(BASE, rel=0.03)
    assert det.noise_rel == pytest.approx(0.03, rel=0.3)
    assert any(math.hypot(i.x_mm - weak[0], i.y_mm - weak[1]) <= 1.5 for i in det.inclusions)
    assert len(det.inclusions) == len(blobs) + 1
    # the stiff cells were left out of the estimate
    assert det.candidates[np.hypot(*np.meshgrid(XS - 12.0, XS - 12.0)) <= 4.0].all()


def test_the_threshold_follows_the_false_alarm_rate_and_the_maps_area() -> None:
    cfg = _calibrated()
    strict = replace(cfg, false_alarm_per_map=0.001)
    area = cfg.gumbel[2]
    assert threshold_for(area, strict) > threshold_for(area, cfg)
    assert threshold_for(4 * area, cfg) > threshold_for(area, cfg)   # more cells, more chances
    t = threshold_for(area, cfg)
    assert false_alarm_probability(t, area, cfg) == pytest.approx(cfg.false_alarm_per_map, rel=1e-9)
    assert false_alarm_probability(t + 1, area, cfg) < cfg.false_alarm_per_map
    # a weak inclusion passes a lax threshold and not a strict one, and says how likely a blank map shows as much
    grid = _field([(30.0, 30.0, 3.5, 1.12)], noise=0.04, seed=2)
    lax = detect(_snap(grid), replace(cfg, false_alarm_per_map=0.2))
    assert len(lax.inclusions) == 1
    p = lax.inclusions[0].false_alarm
    assert detect(_snap(grid), replace(cfg, false_alarm_per_map=p * 0.5)).inclusions == []
    assert len(detect(_snap(grid), replace(cfg, false_alarm_per_map=min(0.99, p * 2))).inclusions) == 1


def test_two_close_inclusions_are_two_detections() -> None:
    """5 mm of tissue between them: the larger discs join their halos into one region, the smallest disc's
    significance shows the dip between them."""
    det = detect(_snap(_field([(22.0, 30.0, 4.0, 1.6), (38.0, 30.0, 4.0, 1.6)], noise=0.04, seed=7)), _calibrated())
    assert sorted(round(i.x_mm) for i in det.inclusions) == [22, 38]
    assert all(abs(i.y_mm - 30.0) < 1.0 and abs(i.x_mm - round(i.x_mm)) < 1.0 for i in det.inclusions)


def test_a_missed_line_is_bridged_and_an_unscanned_corner_is_no_inclusion() -> None:
    grid = _field([(21.0, 31.0, 4.0, 2.0)], noise=0.04, seed=3)
    grid[:, 10] = np.nan   # one missed line through the inclusion
    grid[22:, 22:] = np.nan   # a corner never visited
    det = detect(_snap(grid), _calibrated())
    assert len(det.inclusions) == 1
    assert math.hypot(det.inclusions[0].x_mm - 21.0, det.inclusions[0].y_mm - 31.0) <= 1.0


def test_a_partial_maps_background_does_not_bend_to_a_fair_segment_over_an_inclusion() -> None:
    """A sparse lattice of eight 3-cell segments is the fair sample (``estimate_from``), one of them over an
    inclusion at the map's corner, whose disc is revealed at full density (bench/adaptive_staged.py's oracle on
    fresh seed 14506: 25 σ on the raster, 0.7 σ on such a map). From a least-squares start the quadratic through 24
    cells sits at the segment's level and the inclusion vanishes; started from the biweights of the cells'
    deviations from their median, it is found on every draw."""
    xs, ys = np.arange(21) * CELL + 7.0, np.arange(19) * CELL + 7.0
    gy, gx = np.meshgrid(ys, xs, indexing="ij")
    fair = np.zeros(gx.shape, dtype=bool)
    for x0, y0 in [(7, 31), (23, 31), (43, 31), (11, 19), (27, 19), (7, 7), (23, 7), (43, 7)]:
        fair |= (gx == x0) & (gy >= y0) & (gy <= y0 + 4)
    inclusion = np.hypot(gx - 43.5, gy - 33.5) <= 4.3
    shown = fair | (np.hypot(gx - 43.5, gy - 33.5) <= 5.3)
    for seed in range(5):
        noise = np.exp(0.03 * np.random.default_rng(seed).standard_normal(gx.shape))
        grid = np.where(shown, BASE * np.where(inclusion, 1.4, 1.0) * noise, np.nan)
        snap = MapSnapshot(grid, xs, ys, np.ones(gx.shape, dtype=np.int64), np.zeros(gx.shape), CELL)
        det = detect(snap, estimate_from=fair)
        assert [round(i.x_mm / 4) for i in det.inclusions] == [11], seed
        assert abs(math.log(float(det.background[13, 18]) / BASE)) < 0.1, seed   # under the inclusion: the tissue's


def _columns_map(blobs: list[tuple[float, float, float, float]], seed: int) -> npt.NDArray[np.float64]:
    """``_field`` seen only on columns 8 mm apart (x = 5, 13, ... 53 mm): a sparse lattice, NaN between."""
    gy, gx = np.meshgrid(XS, XS, indexing="ij")
    return np.where((gx - 5.0) % 8.0 == 0, _field(blobs, noise=0.04, seed=seed), np.nan)


def test_an_inclusion_seen_in_pieces_across_unmeasured_cells_is_one_inclusion() -> None:
    """Two columns of a sparse lattice cross one inclusion 4 mm either side of its centre; the 6 mm between them
    was never measured. Each column's piece stands far above the threshold: two regions. Joined across the blind
    cells they are one inclusion, at the centre; a wider gap than ``join_gap_mm`` is not bridged, and healthy
    measured cells between two regions keep them apart."""
    one = [(33.0, 31.0, 5.0, 2.0)]
    for seed in range(3):
        snap = _snap(_columns_map(one, seed))
        apart = detect(snap, _calibrated())
        assert sorted(round(i.x_mm) for i in apart.inclusions) == [29, 37], seed   # the pieces, off its centre
        blind = ~np.isfinite(snap.stiffness)
        joined = detect(snap, replace(_calibrated(), join_gap_mm=6.0), unmeasured=blind).inclusions
        assert len(joined) == 1 and abs(joined[0].x_mm - 33.0) < 1.0 and abs(joined[0].y_mm - 31.0) < 1.0, seed
        narrow = detect(snap, replace(_calibrated(), join_gap_mm=4.0), unmeasured=blind).inclusions  # 2 cells < 3
        assert len(narrow) == 2, seed
        # the cells between are not said to be unmeasured tissue (off the specimen, say): nothing joins across them
        assert len(detect(snap, replace(_calibrated(), join_gap_mm=6.0)).inclusions) == 2, seed
        elsewhere = blind & ((snap.x_mm[None, :] < 29.0) | (snap.x_mm[None, :] > 37.0))
        assert len(detect(snap, replace(_calibrated(), join_gap_mm=6.0), unmeasured=elsewhere).inclusions) == 2
    # two inclusions on neighbouring columns with measured healthy cells between them along the column: two
    two = [(29.0, 15.0, 3.0, 2.0), (37.0, 45.0, 3.0, 2.0)]
    for seed in range(3):
        snap = _snap(_columns_map(two, seed))
        cfg = replace(_calibrated(), join_gap_mm=6.0)
        found = detect(snap, cfg, unmeasured=~np.isfinite(snap.stiffness)).inclusions
        assert sorted((round(i.x_mm), round(i.y_mm)) for i in found) == [(29, 15), (37, 45)], seed
    # two inclusions, one on each column, 6 mm of blind cells apart on the diagonal but their peaks 11 mm apart:
    # more than one inclusion's breadth (join_span_mm), two; with a span that allows it they would be one
    diagonal = [(29.0, 15.0, 3.0, 2.0), (37.0, 23.0, 3.0, 2.0)]
    for seed in range(3):
        snap = _snap(_columns_map(diagonal, seed))
        cfg = replace(_calibrated(), join_gap_mm=6.0, join_span_mm=10.0)
        found = detect(snap, cfg, unmeasured=~np.isfinite(snap.stiffness)).inclusions
        assert sorted((round(i.x_mm), round(i.y_mm)) for i in found) == [(29, 15), (37, 23)], seed
        loose = detect(snap, replace(cfg, join_span_mm=20.0), unmeasured=~np.isfinite(snap.stiffness)).inclusions
        assert [(round(i.x_mm), round(i.y_mm)) for i in loose] == [(33, 19)], seed
    # a whole map (nothing unmeasured): the same detections with or without the joining
    whole = _snap(_field([(20.0, 20.0, 4.0, 1.6), (26.0, 30.0, 4.0, 1.6)], noise=0.04, seed=3))
    assert (detect(whole, _calibrated()).inclusions
            == detect(whole, replace(_calibrated(), join_gap_mm=20.0), unmeasured=np.ones((30, 30), bool)).inclusions)


def test_degenerate_maps_detect_nothing() -> None:
    assert detect(StiffnessGrid(0, 0, 10, 10, 1.0).snapshot(), _calibrated()).inclusions == []   # no data
    negative = _snap(np.full((30, 30), -1.0))   # no positive stiffness: no valid cell
    det = detect(negative, _calibrated())
    assert det.inclusions == [] and math.isnan(det.baseline)
    smooth = _snap(_field([], noise=0.0, seed=0))   # no noise at all: the floor keeps wrinkles insignificant
    assert detect(smooth, _calibrated()).inclusions == []
    for bad in ({"radii_mm": ()}, {"false_alarm_per_map": 0.0}, {"candidate_snr": 0.0}, {"iterations": 0},
                {"noise_floor_rel": 0.0}, {"join_gap_mm": -1.0},
                {"join_span_mm": -1.0}):
        with pytest.raises(ValueError, match="DetectorConfig"):
            DetectorConfig(**bad)  # type: ignore[arg-type]


def test_inclusions_json_carries_the_significance() -> None:
    det = detect(_snap(_field([(30.0, 30.0, 5.0, 2.0)], noise=0.04, seed=5)), _calibrated())
    rec = to_inclusions_json(det.inclusions)[0]
    assert set(rec) == {"x_mm", "y_mm", "radius_mm", "contrast", "snr", "false_alarm"}
    assert rec["snr"] == det.inclusions[0].snr and 0 <= rec["false_alarm"] < 1
    assert json.loads(json.dumps(rec)) == rec


def _planner_map(name: str) -> tuple[MapSnapshot, npt.NDArray[np.bool_]]:
    """An adaptive planner's final detection map and its fair cells, as bench/adaptive.py's runs wrote them
    (tests/data/partial_map_*.json: the GP-filled map the planner detects on, NaN where it shows nothing)."""
    d = json.loads((Path(__file__).parent / "data" / f"partial_map_{name}.json").read_text())
    grid = np.array([[math.nan if v is None else v for v in row] for row in d["stiffness_kpa"]], dtype=np.float64)
    fair = np.array([[c == "1" for c in row] for row in d["fair"]], dtype=bool)
    snap = MapSnapshot(grid, np.array(d["x_mm"]), np.array(d["y_mm"]), np.ones(grid.shape, dtype=np.int64),
                       np.zeros(grid.shape), CELL)
    return snap, fair


def test_a_partial_maps_background_is_fitted_again_without_corner_inclusions_when_that_lowers_its_noise() -> None:
    """Spent seed 15005: four inclusions near the corners hold 21 of the sparse lattice's 73 fair cells, and the
    quadratic bends up to them even from the robust start: noise 0.098 (a blank map's: 0.03), nothing reported. Fitted
    again without the cells far above a plane, the noise falls to 0.03 and all four are found where they are. On
    seed 15016 (a dome with three inclusions) the second fit lowers the noise too little to be kept, and the detections
    are the first fit's to the bit: kept, it would extrapolate the dome's top into its edges."""
    law = with_law_of(DetectorConfig(), "airfloat", partial=True)
    off = replace(law, guard_noise_ratio=0.0)
    snap, fair = _planner_map("15005")
    blind = ~np.isfinite(snap.stiffness)
    plain = detect(snap, off, estimate_from=fair, unmeasured=blind)
    assert plain.inclusions == [] and plain.noise_rel > 0.08
    det = detect(snap, law, estimate_from=fair, unmeasured=blind)
    assert det.noise_rel < 0.04
    truth = [(16.79, 52.41, 5.82), (33.38, 45.85, 4.58), (12.65, 9.04, 4.45), (31.96, 11.64, 3.04)]
    assert len(det.inclusions) == 4
    for x, y, r in truth:
        assert any(math.dist((x, y), (i.x_mm, i.y_mm)) <= r + 1.0 for i in det.inclusions), (x, y)
    snap, fair = _planner_map("15016")
    blind = ~np.isfinite(snap.stiffness)
    plain = detect(snap, off, estimate_from=fair, unmeasured=blind)
    kept = detect(snap, law, estimate_from=fair, unmeasured=blind)
    assert kept.noise_rel == plain.noise_rel and kept.inclusions == plain.inclusions and len(plain.inclusions) == 3
    # a whole map is never fitted twice: the raster's detections are what they were
    whole = _snap(_field([(20.0, 20.0, 4.0, 1.6), (45.0, 45.0, 6.0, 2.0)], noise=0.04, seed=5, dome=0.3))
    assert detect(whole, off).inclusions == detect(whole, law).inclusions


def test_raised_above_plane_names_a_plateau_on_a_tilt_not_the_tilt() -> None:
    """The guard's cells: those far above a robust plane. A tilted field with white noise and a raised square names
    the square's cells and no others (at 4 σ: no noise cell of 900 reaches it); too few cells name none."""
    rng = np.random.default_rng(3)
    gy, gx = np.meshgrid(XS, XS, indexing="ij")
    logs = 3.0 + 0.01 * gx - 0.005 * gy + 0.03 * rng.standard_normal(gx.shape)
    square = (gx > 40) & (gy > 40)
    logs = np.where(square, logs + 0.5, logs)
    use = np.ones(gx.shape, dtype=bool)
    assert np.array_equal(raised_above_plane(logs, use, XS, XS, 4.0), square)   # 0.5 against 0.03 of noise
    few = np.zeros(gx.shape, dtype=bool)
    few[0, :10] = True
    assert not raised_above_plane(logs, few, XS, XS, 2.5).any()
