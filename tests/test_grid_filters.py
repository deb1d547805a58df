"""models.grid_filters against scipy.ndimage, which it replaces in the map detector: the same results to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from models.detector import _disc
from models.grid_filters import dilate, disc_sum, label8

EIGHT = np.ones((3, 3), dtype=bool)


def _grids(seed: int, n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        ny, nx = (int(v) for v in rng.integers(1, 33, 2))
        g = rng.normal(size=(ny, nx)) * float(rng.choice([1e-3, 1.0, 1e3]))
        g[rng.random((ny, nx)) < 0.2] = 0.0
        if i % 5 == 0:
            g[rng.random((ny, nx)) < 0.2] = -0.0  # ndimage starts each sum from +0.0
        out.append(g)
    return out


def test_disc_sum_is_ndimage_convolve_to_the_bit() -> None:
    for g in _grids(1, 300):
        for radius, cell in ((2.5, 2.0), (3.5, 2.0), (5.0, 2.0), (7.0, 2.0), (1.0, 1.0), (4.0, 0.5)):
            k = _disc(radius, cell)
            ours, theirs = disc_sum(g, k), ndimage.convolve(g, k, mode="constant")
            assert ours.tobytes() == theirs.tobytes(), (g.shape, radius, cell)  # signs of zero included


def test_label8_numbers_regions_as_ndimage_label() -> None:
    rng = np.random.default_rng(2)
    for _ in range(400):
        ny, nx = (int(v) for v in rng.integers(1, 40, 2))
        mask = rng.random((ny, nx)) < rng.random()
        ours, n = label8(mask)
        theirs, m = ndimage.label(mask, structure=EIGHT)
        assert n == m and np.array_equal(ours, theirs)


def test_label8_joins_a_long_spiral_and_diagonal_neighbours() -> None:
    n = 41
    spiral = np.zeros((n, n), dtype=bool)
    for i in range(0, n // 2, 2):  # rings joined at one corner each: one region as long as the grid's area allows
        spiral[i, i : n - i] = spiral[i : n - i, n - 1 - i] = spiral[n - 1 - i, i : n - i] = True
        spiral[i + 2 : n - i, i] = True
    ours, count = label8(spiral)
    theirs, m = ndimage.label(spiral, structure=EIGHT)
    assert count == m and np.array_equal(ours, theirs)
    diagonal = np.eye(5, dtype=bool)
    assert label8(diagonal)[1] == 1  # corners touch: one region (a 4-connected labelling finds five)


def test_dilate_is_ndimage_binary_dilation() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        ny, nx = (int(v) for v in rng.integers(1, 30, 2))
        mask = rng.random((ny, nx)) < 0.1
        s = _disc(float(rng.choice([2.5, 5.0, 7.0])), 2.0) > 0
        assert np.array_equal(dilate(mask, s), ndimage.binary_dilation(mask, structure=s))


def test_refuses_what_it_does_not_compute() -> None:
    with pytest.raises(ValueError, match="0/1"):
        disc_sum(np.ones((4, 4)), np.full((3, 3), 0.5))
    with pytest.raises(ValueError, match="odd"):
        disc_sum(np.ones((4, 4)), np.ones((2, 2)))
    lopsided = np.zeros((3, 3))
    lopsided[0, 0] = lopsided[1, 1] = 1.0
    with pytest.raises(ValueError, match="half turn"):
        dilate(np.ones((4, 4), dtype=bool), lopsided > 0)
