"""bench/adaptive_bound.py's geometric bound on the raster's finds a planner at a probe ratio leaves unsensed."""

from __future__ import annotations

import math
from types import ModuleType

import pytest

from tests.procs import bench_module


def _bench() -> ModuleType:
    return bench_module("adaptive_bound")


def test_an_inclusion_hides_where_the_sweeps_stadiums_cannot_reach() -> None:
    b = _bench()
    # ratio 0.1 of a 3 mm raster in 6 mm sweeps; r 1 + reach 1: each sweep senses 2*2*6 + pi*4 mm^2
    assert b.hide_probability(1.0, 1.0, 0.1, 3.0, 6.0) == pytest.approx(1 - 0.1 * (4 + math.pi * 4 / 6) / 3)
    assert b.hide_probability(6.0, 1.5, 0.2, 3.0, 6.0) == 0.0  # its stadiums could cover the whole region
    assert b.hide_probability(1.0, 1.0, 0.1, 3.0, 1e9) == pytest.approx(1 - 0.1 * 4 / 3)  # long lines: bands
    rows = [{"radius_mm": "1.0", "raster": "3"}, {"radius_mm": "6.0", "raster": "2"}, {"radius_mm": "0.5", "raster": "0"}]
    assert b.expected_unsensed(rows, 1.0, 0.1, 3.0, 6.0) == pytest.approx(3 * b.hide_probability(1.0, 1.0, 0.1, 3.0, 6.0))


def test_the_detection_bound_is_wald_hoeffdings_divergence_budget() -> None:
    b = _bench()
    # nothing kept: d(1, a) = ln(1/a) = f s^2 / 2
    assert b.least_miss(5.0, 0.2, 0.0) == pytest.approx(math.exp(-0.2 * 25 / 2), rel=1e-9)
    # a tenth of the blank places kept: the root of d(0.9, a) = f s^2 / 2, smaller than with none kept
    a = b.least_miss(5.0, 0.2, 0.1)
    assert 0.9 * math.log(0.9 / a) + 0.1 * math.log(0.1 / (1 - a)) == pytest.approx(0.2 * 25 / 2, rel=1e-9)
    assert a < b.least_miss(5.0, 0.2, 0.0)
    # more spent or a stronger inclusion: fewer misses; one far above the noise: none (no underflow)
    assert b.least_miss(5.0, 0.25, 0.1) < a and b.least_miss(6.0, 0.2, 0.1) < a
    assert b.least_miss(150.0, 0.2, 0.1) == 0.0 and b.least_miss(150.0, 0.2, 0.0) == 0.0
