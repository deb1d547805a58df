"""bench/adaptive.py's yardstick: what a planner's probes are counted against."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from bench.adaptive import LENGTH_MM, raster_probe_equivalents


def test_a_probe_is_one_sweep_of_the_planners_own_length() -> None:
    """The raster's swept length (lines every 3 mm) in the planner's sweeps: 7 lines over 18 mm, 42 mm each, are 49
    sweeps of the default 6 mm and 73.5 of 4 mm; a planner of shorter sweeps is not credited for their length."""
    spec = SimpleNamespace(overrides={"region_mm": [0.0, 0.0, 18.0, 42.0]})
    assert LENGTH_MM == 6.0
    assert raster_probe_equivalents(spec) == pytest.approx(49.0)   # type: ignore[arg-type]
    assert raster_probe_equivalents(spec, sweep_mm=4.0) == pytest.approx(73.5)   # type: ignore[arg-type]
    assert raster_probe_equivalents(spec, camera=True) == pytest.approx(5 * 11)   # type: ignore[arg-type]
