"""map.png drawn by a helper process (nodes.mapping.map_output.PngHelper): the same picture, a fallback, no
process left."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.stiffness_map import Inclusion
from nodes.mapping.map_output import PngHelper, write_outputs
from tests.test_map_output import _snap

pytestmark = pytest.mark.system  # starts a process

_FOUND = [Inclusion(x_mm=6.0, y_mm=4.0, radius_mm=2.0, contrast=1.4, peak=14.0, area_mm2=16.0, cells=4)]


def test_the_helper_draws_the_same_picture_and_ends(tmp_path: Path) -> None:
    grey = np.zeros((4, 6), dtype=bool)
    grey[:, 5] = True
    helper = PngHelper()
    try:
        write_outputs(tmp_path / "helped", _snap(), _FOUND, unit="kPa", title="run\n12 samples", helper=helper,
                      incomplete="the scan did not finish", unsensed=grey)
        assert helper._proc is None   # used once
    finally:
        helper.close()
    write_outputs(tmp_path / "here", _snap(), _FOUND, unit="kPa", title="run\n12 samples",
                  incomplete="the scan did not finish", unsensed=grey)
    assert (tmp_path / "helped" / "map.png").read_bytes() == (tmp_path / "here" / "map.png").read_bytes()


def test_a_failed_helper_leaves_the_picture_to_the_caller(tmp_path: Path) -> None:
    helper = PngHelper()
    assert helper._proc is not None
    helper._proc.kill()   # died while the scan ran
    helper._proc.wait(10)
    write_outputs(tmp_path, _snap(), _FOUND, unit="kPa", title="t", helper=helper)
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    write_outputs(tmp_path / "again", _snap(), _FOUND, unit="kPa", title="t", helper=helper)  # a second map
    assert (tmp_path / "again" / "map.png").is_file()


def test_an_unused_helper_is_ended_by_close() -> None:
    helper = PngHelper()
    proc = helper._proc
    assert proc is not None
    helper.close()
    assert proc.returncode == 0   # it saw the end of its input and exited by itself
    helper.close()   # idempotent
