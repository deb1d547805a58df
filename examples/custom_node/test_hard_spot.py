"""The node plugged into the scan: its logic on the in-memory bus, its launch file checked, its message type
recorded by a launch with no setting."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hard_spot import HardSpots

from messages import StiffnessSample
from palpa.launch import load_launch
from palpa.testing import NodeHarness

HERE = Path(__file__).resolve().parent


def sample(x: float, value: float, valid: bool = True) -> StiffnessSample:
    return StiffnessSample(stamp_ns=int(x), model="airfloat", x_mm=x, y_mm=1.0, z_mm=0.0, value=value, unit="kPa",
                           valid=valid, reason="" if valid else "no_contact")


def test_reports_samples_stiffer_than_the_recent_median() -> None:
    with NodeHarness(HardSpots, {"threshold": 1.5, "window": 5}) as h:
        for x, v in enumerate([26.0, 27.0, 25.0, 26.0, 39.5, 38.0, 26.0]):
            h.publish("stiffness/sample", sample(float(x), v))
        h.publish("stiffness/sample", sample(9.0, 500.0, valid=False))  # invalid: ignored
        spots = h.published("hard_spots")
    assert [(s.x_mm, s.value) for s in spots] == [(4.0, 39.5)]  # 38.0 is under 1.5 x 26
    assert spots[0].ratio == 39.5 / 26.0 and spots[0].unit == "kPa"


def test_the_scan_with_it_checks(tmp_path: Path) -> None:
    plan = load_launch(HERE / "scan_with_hard_spots.yaml", run_dir=tmp_path / "run")
    assert plan.progress_topic == "robot/scan_status" and plan.record is not None
    assert [n.name for n in plan.nodes][-1] == "hard_spots" and "scanner" in plan.node_params
    rec = plan.recorder()
    assert rec is not None and "hard_spot" in rec.env["PALPA_NODE_MODULES"].split(",")


def _recorder_finds_schema(node_modules: str) -> str:
    code = "from palpa.record.format import schema_bytes; print(schema_bytes('HardSpot') is not None)"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), str(HERE.parents[1])]),
           "PALPA_NODE_MODULES": node_modules, "PALPA_MESSAGES": ""}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=60).stdout.strip()


@pytest.mark.system  # starts a process: make test-system
def test_a_launched_recorder_finds_the_custom_type_with_no_setting() -> None:
    assert _recorder_finds_schema("nodes.demo,hard_spot") == "True"
    assert _recorder_finds_schema("") == "False"  # what the recorder had before: no schema for HardSpot
