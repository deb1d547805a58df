"""Issue 14: a graph that knows only what a rig knows. Every launch file is loaded (no process starts) and no
node but a simulated driver may be given a phantom, under any parameter name."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from palpa.launch import load_launch

REPO = Path(__file__).resolve().parent.parent
PHANTOMS = (REPO / "phantoms").resolve()
MEASURED = PHANTOMS / "measured"
FILES = sorted((REPO / "launch").glob("*.yaml"))
# Nodes with no hardware counterpart behind a driver switch: the camera paper's evaluation stage is a simulated
# fixture (on the rig the stage is given surface_z_mm).
SIM_ONLY = {"nodes.scanner.linear_stage:LinearStage"}
REQUIRED_ARGS = {"replay_scan.yaml": {"bag": "/tmp/a-recording.mcap", "calibration": "",
                                      "geometry": str(MEASURED / "airfloat_tumours.yaml")}}


def phantom_values(value: Any) -> list[str]:
    """Every string in a parameter value that names a phantom file (measured-geometry files excepted)."""
    if isinstance(value, dict):
        return [s for v in value.values() for s in phantom_values(v)]
    if isinstance(value, list):
        return [s for v in value for s in phantom_values(v)]
    if isinstance(value, str) and value.endswith((".yaml", ".yml")):
        path = (REPO / value).resolve()
        if path.is_relative_to(PHANTOMS) and not path.is_relative_to(MEASURED):
            return [value]
    return []


def given_a_phantom(file: Path, overrides: dict[str, Any]) -> dict[str, tuple[str, Any]]:
    """node name -> (target, driver param) for every node whose params name a phantom file."""
    plan = load_launch(file, overrides, run_dir="/tmp/unused")
    return {n.name: (n.target or "", n.params.get("driver")) for n in plan.nodes
            if phantom_values(n.params) or n.params.get("phantom")}


@pytest.mark.parametrize("file", FILES, ids=[f.name for f in FILES])
def test_only_simulated_drivers_get_a_phantom(file: Path) -> None:
    for name, (target, driver) in given_a_phantom(file, REQUIRED_ARGS.get(file.name, {})).items():
        assert driver == "sim" or target in SIM_ONLY, f"{file.name}: node {name!r} ({target}, driver {driver!r}) " \
                                                      "is given a phantom file"


def test_the_rig_file_with_simulated_probe_drivers_gives_the_phantom_to_them_only() -> None:
    over = {"fibre_driver": "sim", "pressure_driver": "sim", "phantom": "phantoms/airfloat_tumours.yaml"}
    assert given_a_phantom(REPO / "launch" / "scan_ur.yaml", over) == {
        "fibre": ("nodes.probe.fibre_reader:FibreReader", "sim")}


def test_the_check_sees_a_phantom_under_any_name(tmp_path: Path) -> None:
    """The check itself can fail: an estimator handed the phantom as its 'geometry' is caught."""
    f = tmp_path / "bad.yaml"
    f.write_text(f"nodes:\n  - name: estimator\n    node: nodes.probe.stiffness_estimator:AirfloatStiffnessEstimator\n"
                 f"    params: {{geometry: {PHANTOMS / 'flat_26k.yaml'}}}\n")
    assert given_a_phantom(f, {}) == {"estimator": ("nodes.probe.stiffness_estimator:AirfloatStiffnessEstimator", None)}
