"""The scan's output files (nodes.mapping.map_output): the adaptive planner's unsensed grid beside the map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.stiffness_map import Inclusion, MapSnapshot
from nodes.mapping.map_output import write_outputs


def _snap() -> MapSnapshot:
    xs, ys = np.arange(6) * 2.0 + 1.0, np.arange(4) * 2.0 + 1.0
    grid = np.full((4, 6), 10.0)
    grid[1:3, 2:4] = 14.0
    return MapSnapshot(stiffness=grid, x_mm=xs, y_mm=ys, count=np.ones((4, 6), dtype=np.int64),
                       spread=np.full((4, 6), 0.5), resolution_mm=2.0)


def test_the_unsensed_cells_are_kept_in_map_npz_and_greyed_in_map_png(tmp_path: Path) -> None:
    found = [Inclusion(x_mm=6.0, y_mm=4.0, radius_mm=2.0, contrast=1.4, peak=14.0, area_mm2=16.0, cells=4)]
    write_outputs(tmp_path / "plain", _snap(), found, unit="kPa", title="t")
    assert "unsensed" not in np.load(tmp_path / "plain" / "map.npz")   # a raster's map has none
    mask = np.zeros((4, 6), dtype=bool)
    mask[:, 5] = True
    write_outputs(tmp_path / "adaptive", _snap(), found, unit="kPa", title="t", unsensed=mask)
    kept = np.load(tmp_path / "adaptive" / "map.npz")["unsensed"]
    assert kept.dtype == bool and np.array_equal(kept, mask)
    # the grey lies over those cells: the same map greyed on the other side is another picture
    write_outputs(tmp_path / "left", _snap(), found, unit="kPa", title="t", unsensed=mask[:, ::-1])
    assert (tmp_path / "adaptive" / "map.png").read_bytes() != (tmp_path / "left" / "map.png").read_bytes()
    with pytest.raises(ValueError, match=r"unsensed: shape \(4, 5\) is not the map's \(4, 6\)"):
        write_outputs(tmp_path / "bad", _snap(), found, unit="kPa", title="t", unsensed=mask[:, :5])
    assert not (tmp_path / "bad").exists()   # nothing half-written
