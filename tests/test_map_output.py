"""The scan's output files (nodes.mapping.map_output): the adaptive planner's unsensed grid beside the map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.stiffness_map import Inclusion, MapSnapshot
from nodes.mapping.map_output import MapNotWritten, write_outputs


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


def test_layers_are_kept_in_map_npz_under_their_names_and_a_bad_one_writes_nothing(tmp_path: Path) -> None:
    """An adaptive planner keeps the grids its detection used beside its map (its measured cells and its
    stiffness-blind ones), so the detection can be run again offline; a layer that would shadow one of the map's
    own arrays, or is not the map's shape, is refused before anything is written."""
    measured = np.where(np.arange(24).reshape(4, 6) % 2 == 0, 12.0, np.nan)
    write_outputs(tmp_path / "a", _snap(), [], unit="kPa", title="t", layers={"measured": measured})
    with np.load(tmp_path / "a" / "map.npz") as kept:
        assert np.array_equal(kept["measured"], measured, equal_nan=True)
        assert np.array_equal(kept["stiffness"], _snap().stiffness)   # the map itself as it was
    with pytest.raises(ValueError, match=r"layer 'stiffness': map.npz has an array of that name"):
        write_outputs(tmp_path / "b", _snap(), [], unit="kPa", title="t", layers={"stiffness": measured})
    with pytest.raises(ValueError, match=r"layer 'fair': shape \(4, 5\) is not the map's \(4, 6\)"):
        write_outputs(tmp_path / "c", _snap(), [], unit="kPa", title="t", layers={"fair": measured[:, :5]})
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


def test_a_folder_the_map_cannot_be_written_to_is_one_error_naming_it(tmp_path: Path) -> None:
    """Whatever the OSError (here the folder lies under a file), the writers' callers get one kind of error, whose
    message names the folder: the map aggregator and the adaptive planner end non-zero on it, saying so."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with pytest.raises(MapNotWritten, match=f"the map could not be written to {blocker / 'map'}"):
        write_outputs(blocker / "map", _snap(), [], unit="kPa", title="t")
