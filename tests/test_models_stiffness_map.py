"""Stiffness map (issue 8): robust per-cell binning, gap filling, the inclusions.json records (the detector:
tests/test_models_detector.py)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from models.stiffness_map import (
    Inclusion,
    StiffnessGrid,
    background,
    fill_gaps,
    to_inclusions_json,
)

BASE = 26.4  # kPa, the papers' background silicone


def field(
    x: np.ndarray, y: np.ndarray, blobs: list[tuple[float, float, float, float]]
) -> np.ndarray:
    """Background plus cylindrical inclusions (cx, cy, radius, stiffness ratio)."""
    v = np.full(np.broadcast(x, y).shape, BASE)
    for cx, cy, r, ratio in blobs:
        v = np.where(np.hypot(x - cx, y - cy) <= r, BASE * ratio, v)
    return v


def scan(
    blobs: list[tuple[float, float, float, float]],
    *,
    seed: int,
    n: int = 40_000,
    noise: float = 0.05,
    keep: object = None,
) -> StiffnessGrid:
    """Dense random samples over a 60 x 60 mm phantom with relative Gaussian noise and 1 %
    wild outliers (x3), binned at 1 mm."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 60, n)
    v = field(x, y, blobs) * (1 + noise * rng.standard_normal(n))
    v[rng.random(n) < 0.01] *= 3.0
    if keep is not None:
        m = keep(x, y)  # type: ignore[operator]
        x, y, v = x[m], y[m], v[m]
    g = StiffnessGrid(0, 0, 60, 60, 1.0)
    g.add(x, y, v)
    return g


def test_grid_shape_centres_and_medians() -> None:
    g = StiffnessGrid(10, 20, 14, 23, 1.0, min_count=2)
    assert (g.nx, g.ny) == (4, 3)
    g.add([10.2, 10.7, 10.5], [20.5, 20.5, 20.1], [1.0, 100.0, 2.0])  # cell (0, 0)
    g.add(14.0, 23.0, 5.0)  # the far corner belongs to the last cell
    g.add([13.5, 13.5], [21.5, 21.5], [7.0, 9.0])
    assert g.add([9.99, 14.01, math.nan, 11.0], [21, 21, 21, 21], [1, 1, 1, math.inf]) == 0
    assert g.dropped == 4 and len(g) == 6
    s = g.snapshot()
    np.testing.assert_allclose(s.x_mm, [10.5, 11.5, 12.5, 13.5])
    np.testing.assert_allclose(s.y_mm, [20.5, 21.5, 22.5])
    assert s.stiffness.shape == s.count.shape == s.spread.shape == (3, 4)
    assert s.count[0, 0] == 3 and s.count[2, 3] == 1 and s.count[1, 3] == 2
    assert s.stiffness[0, 0] == 2.0  # median: the 100 outlier does not move it
    assert s.spread[0, 0] == pytest.approx(1.4826 * 1.0)  # MAD of (1, 2, 100) around 2 is 1
    assert s.stiffness[1, 3] == 8.0  # even count: mean of the middle pair
    assert math.isnan(s.stiffness[2, 3])  # one sample < min_count
    assert np.isnan(s.stiffness).sum() == 12 - 2
    with pytest.raises(ValueError):
        s.stiffness[0, 0] = 1.0  # snapshots are read-only


def test_incremental_and_vectorised_add_agree() -> None:
    rng = np.random.default_rng(0)
    x, y, v = rng.uniform(0, 20, 3000), rng.uniform(0, 10, 3000), rng.normal(5, 1, 3000)
    one = StiffnessGrid(0, 0, 20, 10, 2.0)
    one.add(x, y, v)
    many = StiffnessGrid(0, 0, 20, 10, 2.0)
    for i in range(0, 3000, 7):
        many.add(x[i : i + 7], y[i : i + 7], v[i : i + 7])
        if i % 700 == 0:
            many.snapshot()  # interleaved snapshots must not change the result
    a, b = one.snapshot(), many.snapshot()
    np.testing.assert_array_equal(a.stiffness, b.stiffness)
    np.testing.assert_array_equal(a.spread, b.spread)
    np.testing.assert_array_equal(a.count, b.count)
    # ~60 normal samples per cell: the MAD-based spread estimates sigma = 1.
    assert np.nanmedian(a.spread) == pytest.approx(1.0, abs=0.15)


def _reference_medians(cells: np.ndarray, values: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell median and 1.4826 * MAD by one sort of every sample by (cell, value): what a snapshot computed
    before it kept each cell's samples sorted (issue 40)."""
    count = np.bincount(cells, minlength=n_cells)

    def grouped(v: np.ndarray) -> np.ndarray:
        ordered = v[np.lexsort((v, cells))]
        start = np.cumsum(count) - count
        out = np.full(n_cells, np.nan)
        has = count > 0
        lo, hi = start[has] + (count[has] - 1) // 2, start[has] + count[has] // 2
        out[has] = 0.5 * (ordered[lo] + ordered[hi])
        return out

    median = grouped(values)
    return median, 1.4826 * grouped(np.abs(values - median[cells]))


def test_snapshots_between_adds_give_the_all_at_once_medians_to_the_bit() -> None:
    """A snapshot recomputes only the cells that changed since the last one; the result is the same, bit for bit,
    as sorting every sample at once (ties, even and odd counts, cells under min_count included)."""
    rng = np.random.default_rng(3)
    n = 5000
    x, y = rng.uniform(0, 11, n), rng.uniform(0, 8, n)
    x[[100, 2000, 4999]] = 11.5  # a column of three samples: under min_count
    v = np.round(rng.lognormal(3.0, 0.3, n), 1)  # rounded: many ties within a cell
    g = StiffnessGrid(0, 0, 12, 8, 1.0, min_count=4)
    for i in range(0, n, 37):
        g.add(x[i : i + 37], y[i : i + 37], v[i : i + 37])
        if i % 3 == 0:
            g.snapshot()
    snap = g.snapshot()
    cells = y.astype(np.int64) * g.nx + x.astype(np.int64)
    median, spread = _reference_medians(cells, v, g.nx * g.ny)
    count = np.bincount(cells, minlength=g.nx * g.ny)
    thin = count < 4
    assert thin.any() and (count % 2 == 0).any() and (count % 2 == 1).any()
    median[thin] = np.nan
    spread[thin] = np.nan
    assert snap.count.ravel().tolist() == count.tolist()
    assert snap.stiffness.ravel().tobytes() == median.tobytes()
    assert snap.spread.ravel().tobytes() == spread.tobytes()


def test_grid_rejects_bad_geometry() -> None:
    for args in ((0, 0, 0, 1, 1), (0, 0, 1, 1, 0), (0, 0, math.nan, 1, 1)):
        with pytest.raises(ValueError, match="StiffnessGrid"):
            StiffnessGrid(*args)


def test_fill_gaps_bridges_single_holes_only() -> None:
    g = np.ones((6, 6))
    g[:, 2] = np.nan  # a missed line: filled
    g[0:2, 4:6] = np.nan  # a 2x2 hole in the corner: its cells see < 4 valid neighbours
    out = fill_gaps(g)
    assert np.isfinite(out[:, 2]).all()
    assert np.isnan(out[0, 5]) and np.isnan(g).sum() == 10  # input untouched


def test_background_is_robust_to_inclusions() -> None:
    snap = scan([(15.0, 15.0, 4.0, 6.0), (45.0, 40.0, 6.0, 3.0)], seed=5).snapshot()
    base, sigma = background(snap.stiffness)
    assert base == pytest.approx(BASE, rel=0.01)
    # Per-cell medians of ~11 samples with 5 % noise: about 1.6 % of BASE.
    assert 0.005 * BASE < sigma < 0.03 * BASE
    assert all(math.isnan(v) for v in background(np.full((3, 3), np.nan)))


def test_inclusions_json_matches_design_contract() -> None:
    inc = Inclusion(
        x_mm=1.5, y_mm=2.0, radius_mm=3.0, contrast=4.5, peak=9.0, area_mm2=28.0, cells=28
    )
    out = to_inclusions_json([inc])
    assert out == [{"x_mm": 1.5, "y_mm": 2.0, "radius_mm": 3.0, "contrast": 4.5}]
    assert json.loads(json.dumps(out)) == out
    rec = to_inclusions_json([replace(inc, snr=7.5, false_alarm=1e-4)])[0]
    assert rec == {**out[0], "snr": 7.5, "false_alarm": 1e-4}   # the detector's significance, when known


def test_nanmedian_stack_is_numpys_nanmedian_to_the_bit() -> None:
    """The detector's and the gap filler's median of each 3 x 3 neighbourhood: numpy's nanmedian along the first
    axis, bit for bit (odd and even counts of valid values, ties, columns of NaN alone, infinities)."""
    import warnings

    from models.stiffness_map import nanmedian_stack

    rng = np.random.default_rng(5)
    for rows in (1, 2, 8, 9):
        stack = np.round(rng.lognormal(3.0, 0.5, (rows, 17, 13)), 2)
        stack[rng.random(stack.shape) < 0.4] = np.nan
        stack[:, 0, 0] = np.nan
        stack[0, 1, 1] = np.inf
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            want = np.nanmedian(stack, axis=0)
        got = nanmedian_stack(stack)
        assert got.dtype == want.dtype and got.shape == want.shape
        assert got.tobytes() == want.tobytes()
    counts = (~np.isnan(stack)).sum(axis=0)
    assert {0, 1, 2} <= set(counts.ravel().tolist()) and (counts % 2 == 1).any()
