"""bench/adaptive_bound.py's geometric bound on the raster's finds a planner at a probe ratio leaves unsensed."""

from __future__ import annotations

from types import ModuleType

import pytest

from tests.procs import bench_module


def _bench() -> ModuleType:
    return bench_module("adaptive_bound")


def test_an_inclusion_hides_between_sweeps_as_often_as_the_gap_outgrows_its_sensed_band() -> None:
    b = _bench()
    # ratio 0.2 of a 3 mm raster: sweeps 15 mm apart; r 3 + 1.5 senses a 9 mm band of every 15 mm
    assert b.hide_probability(3.0, 1.5, 0.2, 3.0) == pytest.approx(0.4)
    assert b.hide_probability(6.0, 1.5, 0.2, 3.0) == 0.0  # its band covers the gap
    assert b.hide_probability(6.0, 1.5, 1.0, 3.0) == 0.0  # the raster itself senses everything
    rows = [{"radius_mm": "3.0", "raster": "3"}, {"radius_mm": "6.0", "raster": "2"}, {"radius_mm": "2.0", "raster": "0"}]
    assert b.expected_unsensed(rows, 1.5, 0.2, 3.0) == pytest.approx(3 * 0.4)
