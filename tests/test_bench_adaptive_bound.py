"""bench/adaptive_bound.py's geometric bound on the raster's finds a planner at a probe ratio leaves unsensed."""

from __future__ import annotations

import importlib.util
from types import ModuleType

import pytest

from tests.procs import REPO


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("adaptive_bound", REPO / "bench" / "adaptive_bound.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_an_inclusion_hides_between_sweeps_as_often_as_the_gap_outgrows_its_sensed_band() -> None:
    b = _bench()
    # ratio 0.2 of a 3 mm raster: sweeps 15 mm apart; r 3 + 1.5 senses a 9 mm band of every 15 mm
    assert b.hide_probability(3.0, 1.5, 0.2, 3.0) == pytest.approx(0.4)
    assert b.hide_probability(6.0, 1.5, 0.2, 3.0) == 0.0  # its band covers the gap
    assert b.hide_probability(6.0, 1.5, 1.0, 3.0) == 0.0  # the raster itself senses everything
    rows = [{"radius_mm": "3.0", "raster": "3"}, {"radius_mm": "6.0", "raster": "2"}, {"radius_mm": "2.0", "raster": "0"}]
    assert b.expected_unsensed(rows, 1.5, 0.2, 3.0) == pytest.approx(3 * 0.4)
