"""bench/detector_calibration.py --planner: the law of the planner's maps is fitted from planner.json, named for the
planner it belongs to (a budgeted planner's maps have a law of their own, models.false_alarm.PARTIAL_MAP_LAWS)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.procs import bench_module


def _runs(tmp: Path, budget: list[float]) -> Path:
    rng = np.random.default_rng(0)
    for i, b in enumerate(budget):
        d = tmp / "runs" / f"blank-s{i}" / "map"
        d.mkdir(parents=True)
        top = float(2.5 + 0.3 * rng.gumbel())
        (d / "planner.json").write_text(json.dumps({"detection": {
            "peak_significance": top, "area_mm2": 2080.0, "threshold_snr": 4.2, "budget_fraction": b}}))
    return tmp


def test_the_planners_law_is_named_for_the_planner_it_was_fitted_on(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    b = bench_module("detector_calibration")
    assert b.planner_law([_runs(tmp_path / "plain", [0.0] * 12)]) == 0
    out = capsys.readouterr().out
    assert "ADAPTIVE_GUMBEL_LOC" in out and "BUDGET_" not in out
    assert json.loads(out.strip().splitlines()[-1])["model"] == "adaptive"
    assert b.planner_law([_runs(tmp_path / "budget", [0.2] * 12)]) == 0
    out = capsys.readouterr().out
    assert "BUDGET_GUMBEL_LOC" in out and "BUDGET_GUMBEL_SCALE" in out
    assert json.loads(out.strip().splitlines()[-1])["model"] == "budget"
    with pytest.raises(SystemExit, match="mix budgeted"):
        b.planner_law([_runs(tmp_path / "mixed", [0.0] * 6 + [0.2] * 6)])
