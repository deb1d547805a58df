"""bench/airfloat_reach.py's measure of how far past its edge an inclusion raises a map, on a map made up here."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np

from models.phantom import parse_phantom
from tests.procs import bench_module


def _bench() -> ModuleType:
    return bench_module("airfloat_reach")


def test_the_reach_is_the_farthest_ring_past_the_edge_up_to_which_every_ring_clears_the_suspect_bar(
        tmp_path: Path) -> None:
    ar = _bench()
    ph = parse_phantom({"size_mm": [60, 60], "thickness_mm": 4.0, "youngs_modulus_kpa": 30.0,
                        "inclusions": [{"center_mm": [30, 30], "radius_mm": 4.0, "depth_mm": 1.0,
                                        "youngs_modulus_kpa": 90.0}]})
    xs = ys = np.arange(0.25, 60.0, 0.5)
    gx, gy = np.meshgrid(xs, ys)
    past = np.hypot(gx - 30, gy - 30) - 4.0
    # +30 % up to 1 mm past the edge, +5 % to 2 mm (under the bar: 0.6 x 20 %), the baseline beyond
    stiffness = 30.0 * np.where(past < 1.0, 1.3, np.where(past < 2.0, 1.05, 1.0))
    np.savez(tmp_path / "map.npz", stiffness=stiffness, x_mm=xs, y_mm=ys, count=np.ones_like(stiffness, dtype=int))
    got = ar.profiles(tmp_path / "map.npz", ph, 6.0, 4.0, 0.6)
    assert got is not None
    (means,), bar = got
    assert bar == 0.6 * 0.2   # healthy cells all alike: the detector's floor sets the bar
    # every ring up to 1 mm past the edge clears the bar, the ring 1.0-1.5 mm does not
    assert ar.reach_of(means - bar) == 1.0
    flat = 30.0 * np.where(past < 0.0, 1.1, 1.0)   # +10 % on the inclusion only: not even its rim clears
    np.savez(tmp_path / "flat.npz", stiffness=flat, x_mm=xs, y_mm=ys, count=np.ones_like(flat, dtype=int))
    got = ar.profiles(tmp_path / "flat.npz", ph, 6.0, 4.0, 0.6)
    assert got is not None and ar.reach_of(got[0][0] - got[1]) == -np.inf
