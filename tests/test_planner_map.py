"""An adaptive planner's written map detected again by the planner's own rule (nodes.scanner.planner_map): the same
inclusions as the planner's ``inclusions.json``, a raster's map by the whole-map detector as before, and a planner's
map without what its rule needs refused rather than detected by the whole-map rule."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from models.phantom import load_phantom
from models.stiffness_map import MapSnapshot, to_inclusions_json
from nodes.mapping.map_output import redetect, write_outputs
from nodes.scanner.planner_map import PlannerMapError, redetect_map
from tests.test_adaptive_planner import scanned

REGION = {"region_mm": [0.0, 0.0, 30.0, 30.0]}


def tissue(x: float, y: float) -> float:
    """A strong inclusion at (10, 12) mm and a weak one at (22, 22) mm on a rough background (its roughness a fixed
    function of the place, so that every run sees the same tissue)."""
    rough = 0.04 * np.sin(1.7 * x + 0.3) * np.cos(1.3 * y - 0.5) + 0.03 * np.sin(0.9 * x * y)
    bumps = (1.5 * np.exp(-((x - 10.0) ** 2 + (y - 12.0) ** 2) / 6.0)
             + 0.35 * np.exp(-((x - 22.0) ** 2 + (y - 22.0) ** 2) / 5.0))
    return float(10.0 * (1.0 + bumps) * (1.0 + rough))


@pytest.fixture(scope="module")
def planner_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The output folder of one planner run on :func:`tissue` (default settings): map.npz, inclusions.json,
    planner.json. Read only: a test that edits it works on a copy."""
    out = tmp_path_factory.mktemp("planner") / "map"
    scanned(out, REGION, tissue)
    return out


def own(out: Path) -> list[dict[str, Any]]:
    found: list[dict[str, Any]] = json.loads((out / "inclusions.json").read_text())
    return found


def without(out: Path, tmp: Path, *names: str) -> Path:
    """A copy of the output folder ``out`` whose map.npz lacks the arrays ``names``; its map.npz."""
    copy = tmp / "copy"
    shutil.copytree(out, copy)
    with np.load(copy / "map.npz") as d:
        kept = {k: d[k] for k in d.files if k not in names}
    np.savez(copy / "map.npz", **kept)
    return copy / "map.npz"


def test_a_planners_map_is_detected_again_by_the_planners_own_rule(planner_out: Path) -> None:
    """The planner's map, its settings and layers read back, gives the planner's own detection to the last digit
    (``inclusions.json`` with each inclusion's SNR, and the threshold in planner.json); the whole-map detector on the
    same map is another rule (another law, and its noise from every cell): its significances are not the
    planner's."""
    det, rule = redetect_map(planner_out / "map.npz")
    assert own(planner_out) and to_inclusions_json(det.inclusions) == own(planner_out)
    report = json.loads((planner_out / "planner.json").read_text())["detection"]
    assert round(det.threshold_snr, 4) == report["threshold_snr"]
    assert rule.startswith("the adaptive planner's own rule (airfloat probe's")
    whole = to_inclusions_json(redetect(planner_out / "map.npz").inclusions)
    assert [round(i["snr"], 1) for i in whole] != [round(i["snr"], 1) for i in own(planner_out)]


@pytest.mark.parametrize("params", [{"budget_fraction": 0.3, "fair_halo_mm": 2.0},
                                    {"stop_rule": "lse", "max_probes": 14}], ids=["budget-and-halo", "lse"])
def test_the_planners_other_settings_are_its_rule_again_too(tmp_path: Path, params: dict[str, Any]) -> None:
    """A budgeted planner detects by its own law (heavier-tailed) and leaves the blind cells by a detection out of
    its background; a planner on the lse rule detects on its GP mean: each map detected again gives its own
    inclusions."""
    scanned(tmp_path, {**REGION, **params}, tissue)
    det, _ = redetect_map(tmp_path / "map.npz")
    assert own(tmp_path) and to_inclusions_json(det.inclusions) == own(tmp_path)
    report = json.loads((tmp_path / "planner.json").read_text())["detection"]
    assert round(det.threshold_snr, 4) == report["threshold_snr"]


def test_a_raster_map_goes_the_whole_map_way(tmp_path: Path) -> None:
    """A map without the planner's marks (a raster's, as the map aggregator writes it) is detected again by the
    whole-map detector with its probe's law, as before."""
    axis = np.arange(1.0, 40.0, 2.0)
    yy, xx = np.meshgrid(axis, axis, indexing="ij")
    stiff = np.array([[tissue(x, y) for x in axis] for y in axis])
    snap = MapSnapshot(stiffness=stiff, x_mm=axis, y_mm=axis, count=np.full(stiff.shape, 5, dtype=np.int64),
                       spread=np.full(stiff.shape, 0.3), resolution_mm=2.0)
    write_outputs(tmp_path, snap, [], unit="kPa", title="raster", model="airfloat")
    det, rule = redetect_map(tmp_path / "map.npz")
    assert rule == "the whole-map detector (airfloat probe's false-alarm law)"
    expected = redetect(tmp_path / "map.npz")
    assert det.inclusions and det.inclusions == expected.inclusions and det.threshold_snr == expected.threshold_snr


def test_a_planners_map_without_what_its_rule_needs_is_refused_naming_the_file_and_what_is_missing(
        planner_out: Path, tmp_path: Path) -> None:
    """Written before planner maps kept their settings, or stripped of a layer, a planner's map is no map to detect
    by the whole-map rule instead: the error names the file and what it lacks."""
    npz = without(planner_out, tmp_path / "a", "planner")
    with pytest.raises(PlannerMapError, match=re.escape(f"{npz}: an adaptive planner's map without its settings "
                                                        "('planner'), which its detection rule needs")):
        redetect_map(npz)
    npz = without(planner_out, tmp_path / "b", "fair")
    with pytest.raises(PlannerMapError, match=re.escape(f"{npz}: an adaptive planner's map without the 'fair' "
                                                        "layer(s)")):
        redetect_map(npz)
    # the first planner maps kept neither: told by planner.json beside them, or by the grey of unsensed cells
    npz = without(planner_out, tmp_path / "c", "planner", "measured", "fair")
    with pytest.raises(PlannerMapError, match=r"without its settings \('planner'\) and the 'measured' layer and "
                                              r"the 'fair' layer"):
        redetect_map(npz)
    (npz.parent / "planner.json").unlink()
    with pytest.raises(PlannerMapError, match="without its settings"):
        redetect_map(npz)
    # settings that no longer make the planner's parameters (a parameter since removed) are named too
    npz = without(planner_out, tmp_path / "d")
    with np.load(npz) as d:
        arrays = dict(d)
    kept = json.loads(str(arrays["planner"]))
    kept["params"]["sweep_speed"] = 3.0
    np.savez(npz, **{**arrays, "planner": np.array(json.dumps(kept))})
    with pytest.raises(PlannerMapError, match=r"settings \('planner'\) cannot be read: .*unknown field `sweep_speed`"):
        redetect_map(npz)


def test_scan_report_and_evaluate_redetect_a_planners_map_by_its_rule_and_refuse_one_without_it(
        planner_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``tools.scan_report --redetect`` lists the planner's own inclusions again and says by which rule;
    ``tools.evaluate --redetect`` scores the planner's own detections. A planner's map without its layers: the report
    exits 1 naming the map and what it lacks, the sweep records that as the run's error."""
    from tests.test_evaluate import _fake_run
    from tools.evaluate import redetected, score_outputs
    from tools.scan_report import main

    spec = _fake_run(tmp_path)   # a phantom and a recording; its map replaced by the planner's
    shutil.rmtree(spec.run_dir / "map")
    shutil.copytree(planner_out, spec.run_dir / "map")
    assert main([str(spec.run_dir)]) == 0
    as_written = capsys.readouterr().out.splitlines()
    assert main([str(spec.run_dir), "--redetect"]) == 0
    first, *rest = capsys.readouterr().out.splitlines()
    assert first.startswith("redetected on map.npz by the adaptive planner's own rule (airfloat probe's")
    assert rest == as_written
    phantom = load_phantom(spec.phantom)
    assert score_outputs(spec, phantom, redetect=True) == score_outputs(spec, phantom)
    assert redetected(spec)["ok"]

    npz = without(spec.run_dir / "map", tmp_path / "stripped", "fair")
    shutil.rmtree(spec.run_dir / "map")
    shutil.copytree(npz.parent, spec.run_dir / "map")
    npz = spec.run_dir / "map" / "map.npz"
    assert main([str(spec.run_dir), "--redetect"]) == 1
    assert capsys.readouterr().err.startswith(f"scan_report: cannot detect again: {npz}: an adaptive planner's map "
                                              "without the 'fair' layer(s), which its detection rule reads")
    record = redetected(spec)
    assert not record["ok"] and record["error"].startswith(
        f"cannot score: {npz}: an adaptive planner's map without the 'fair' layer(s)")
