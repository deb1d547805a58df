"""A ROS 2 user's habits (issue 42), in process: every scan launch ends with its result (the camera rig's estimate,
the map of an --in-process scan), the ETA in wall time, the Foxglove URL shown, did-you-means for a launch file and
a message type, a warning for a line spacing the map cannot resolve, and ``palpa run X --help`` with docstrings."""

from __future__ import annotations

import io
import logging
import math
from pathlib import Path

import pytest

from messages import ScanPlan, StiffnessSample
from models.stiffness_map import spacing_warning
from nodes.mapping.map_aggregator import MapAggregator
from nodes.probe.stiffness_estimator import MultiIndenterStiffnessEstimator
from palpa.errors import LaunchError, RegistryError
from palpa.launch import load_launch
from palpa.launch.compose import compose_plan
from palpa.launch.nodeproc import NodeProc
from palpa.launch.output import Screen
from palpa.launch.plan import VIZ_TARGET, NodeSpec
from palpa.launch.progress import ProgressView
from palpa.launch.summary import report_hidden
from palpa.message import lookup
from palpa.node.runner import run_node_code
from palpa.testing import NodeHarness
from tests.test_launch_smoke import REPO

S = 1_000_000_000


def test_an_in_process_scan_reports_its_map_after_the_bar(tmp_path: Path) -> None:
    plan = compose_plan(load_launch(REPO / "launch" / "scan_sim.yaml", {}, run_dir=tmp_path))
    assert plan.progress_report == ["sim:map"]  # the map, composed into the process 'sim'
    sim = NodeProc(NodeSpec(name="sim"), io.StringIO())
    for line in ["INFO palpa.node.scanner: line 3 done", "INFO palpa.node.map: map written: run/map/map.npz",
                 "INFO palpa.node.map: inclusion at (15.0, 18.0) mm, radius 5.5 mm, contrast 1.70",
                 "INFO palpa.node.recorder: recorded 3 messages"]:
        sim.hidden.append(line)
    screen = Screen(io.StringIO(), err := io.StringIO())
    report_hidden(screen, [sim], plan.progress_report)
    shown = screen.out.getvalue().splitlines() + err.getvalue().splitlines()
    assert shown == ["[sim] INFO palpa.node.map: map written: run/map/map.npz",
                     "[sim] INFO palpa.node.map: inclusion at (15.0, 18.0) mm, radius 5.5 mm, contrast 1.70"]
    camera = load_launch(REPO / "launch" / "camera_sim.yaml", {}, run_dir=tmp_path)
    assert camera.progress_report == ["estimator"]


def test_the_camera_estimator_says_its_result_when_it_stops(caplog: pytest.LogCaptureFixture) -> None:
    h = NodeHarness(MultiIndenterStiffnessEstimator, name="estimator")
    def sample(value: float, valid: bool = True) -> StiffnessSample:
        return StiffnessSample(stamp_ns=1, model="multi_indenter", x_mm=0.0, y_mm=0.0, z_mm=0.0, value=value,
                               unit="N/mm", valid=valid, pan_rad=math.radians(2.0), tilt_rad=math.radians(10.0))
    h.node.publish_samples([sample(0.30), sample(0.28), sample(0.32), sample(math.nan, False)])
    assert h.node.result_line() == ("result: stiffness median 0.3 N/mm over 3 valid of 4 samples (10-90 %: 0.28 to "
                                    "0.32); pan median 2.0 deg, tilt median 10.0 deg")
    with caplog.at_level(logging.INFO, logger="palpa.node.estimator"):
        h.close()
    assert any(r.getMessage().startswith("result: stiffness median 0.3 N/mm") for r in caplog.records)
    empty = NodeHarness(MultiIndenterStiffnessEstimator)
    assert empty.node.result_line() == "result: no valid stiffness estimate in 0 samples"
    empty.close()


def test_the_eta_is_given_in_wall_time_beside_the_scans_clock() -> None:
    out = io.StringIO()
    view = ProgressView("robot/scan_status", out, terminal=False)
    # a simulation 4x faster than the wall: each 1 % (1 simulated s) in a quarter wall second; 80 % left: 20 wall s
    for i in range(0, 21):
        view.update({"progress": i / 100, "state": "scanning", "eta_s": 100 - i}, wall_ns=i * S // 4)
    view.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "progress   0% scanning  eta 1:40"  # nothing to pace a wall estimate by yet
    assert lines[-1] == "progress  20% scanning  eta 0:20 wall (1:20 on the scan's clock)"
    assert "eta 1:15" in _terminal_detail()


def _terminal_detail() -> str:
    out = io.StringIO()
    view = ProgressView("t", out, terminal=True)
    view.update({"progress": 0.25, "eta_s": 75})
    view.close()
    return out.getvalue()


def test_the_foxglove_url_is_shown_even_under_a_progress_bar() -> None:
    out = io.StringIO()
    screen = Screen(out, out)
    screen.view = ProgressView("robot/scan_status", out, terminal=False)
    viz = NodeProc(NodeSpec(name="viz", target=VIZ_TARGET), io.StringIO())
    viz.line("palpa viz ready ws://127.0.0.1:8765 (subprotocol foxglove.websocket.v1)", screen)
    other = NodeProc(NodeSpec(name="talker", target="nodes.demo:Talker"), io.StringIO())
    other.line("palpa viz ready ws://elsewhere:1 (not the bridge)", screen)
    assert out.getvalue().splitlines() == [
        "[launch] Foxglove: open ws://127.0.0.1:8765 in the Foxglove app (Open connection -> Foxglove WebSocket; "
        "docs/foxglove.md)"]


def test_the_reason_a_node_failed_survives_a_traceback_printed_after_it() -> None:
    """Seen in CI: Ctrl-C reached the map's picture helper too, whose 30-line traceback pushed the map's ERROR out
    of the kept tail, and the summary said only 'failed: sim'. The last ERROR line is kept apart from the tail."""
    screen = Screen(io.StringIO(), io.StringIO())
    sim = NodeProc(NodeSpec(name="sim"), io.StringIO())
    sim.line("ERROR palpa.node.map: the map is INCOMPLETE and may be wrong: the scan did not finish", screen)
    for i in range(40):
        sim.line(f'  File "scipy/sparse/_base.py", line {i}, in <module>', screen)
    sim.line("WARNING nodes.mapping.map_output: map.png helper failed (exit code -2): drawing it here", screen)
    assert sim.last_error() == "palpa.node.map: the map is INCOMPLETE and may be wrong: the scan did not finish"
    sim.line("CRITICAL palpa.node.scanner: " + "x" * 400, screen)
    assert sim.last_error().startswith("palpa.node.scanner: xxx") and len(sim.last_error()) == 300
    assert NodeProc(NodeSpec(name="quiet"), io.StringIO()).last_error() == ""


def test_did_you_mean_for_a_launch_file_and_a_message_type() -> None:
    with pytest.raises(LaunchError, match=r"scan_sm.yaml: no such launch file \(did you mean '.*launch/scan_sim.yaml'"
                                          r"\?\)"):
        load_launch(REPO / "launch" / "scan_sm.yaml")
    with pytest.raises(RegistryError, match=r"unknown message type 'Estop' \(did you mean 'EStop'\?\)"):
        lookup("Estop")
    with pytest.raises(LaunchError, match="no such launch file$"):
        load_launch(REPO / "nowhere" / "x.yaml")


def test_a_line_spacing_the_map_cannot_resolve_is_warned_about(caplog: pytest.LogCaptureFixture) -> None:
    assert spacing_warning(4.0, 2.0) == "" and spacing_warning(3.0, 2.0) == ""
    text = spacing_warning(6.0, 2.0)
    assert text.startswith("line spacing 6 mm leaves 2 empty rows of 2 mm cells between raster lines")
    assert "use spacing_mm <= 4 (twice resolution_mm) or resolution_mm >= 3 (half the spacing)" in text
    plan = ScanPlan(stamp_ns=1, mode="sweep", region_mm=(0.0, 0.0, 20.0, 20.0), spacing_mm=6.0, speed_mm_s=20.0,
                    lines=4, estimated_duration_s=10.0, waypoints=[])
    with caplog.at_level(logging.WARNING, logger="palpa.node.map"), \
            NodeHarness(MapAggregator, {"output_dir": "unused"}, name="map") as h:
        h.publish("robot/plan", plan)
        h.publish("robot/plan", plan)  # a plan published again is not warned about again
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warned == [text]


def test_palpa_run_help_lists_params_with_their_docstrings(capsys: pytest.CaptureFixture[str]) -> None:
    from nodes.demo import Talker

    with pytest.raises(SystemExit):
        run_node_code(Talker, ["--help"], prog="nodes.demo:Talker")
    out = capsys.readouterr().out
    assert "  rate_hz: float = 10.0  [run-time changeable]\n      > 0; Applied at once when changed at run time" in out
    assert "  count: int = 0  [run-time changeable]\n      Stop (exit 0) after this many messages; 0 runs" in out
