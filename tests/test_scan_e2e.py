"""The product's main job end to end (issues 8 and 9): scans that find the tumours, with the sim arm and with
the ur_rtde driver through the UR emulator, and a recording that replays into the same map."""

from __future__ import annotations

import importlib
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial import cKDTree

import palpa
from emulators.clock_file import ClockWriter
from messages import RobotPose
from models.phantom import load_phantom
from nodes.scanner.robot_scanner import RobotScanner
from palpa.launch import load_launch, parse_overrides
from palpa.testing import GraphHarness
from palpa.timing.clock import MockClock
from tests.followed_clock import FollowedClock
from tests.procs import ProcessGroup, palpa_cmd, ur_emulator
from tests.test_launch_smoke import REPO

UR_OFFSET = (300.0, -40.0, 100.0)  # the phantom's origin in the robot's base frame (mm): the driver maps the frames
UR_SCAN = ["fibre_driver:=sim", "pressure_driver:=sim", "phantom:=phantoms/airfloat_tumours.yaml",
           # 12 x 12 mm over the r 5 x4 tumour at (45, 18): five lines, ~7 s of wall-clock motion
           "region_mm:=[39.0, 12.0, 51.0, 24.0]", "spacing_mm:=3.0", "speed_mm_s:=20.0", "home_mm:=[39.0, 12.0, 9.0]",
           f"frame_offset_mm:={list(UR_OFFSET)}"]
UR_MOVES = {"retract_clearance_mm": 3.0, "approach_clearance_mm": 2.0, "accel_mm_s2": 1000.0}
"""Short hops between the lines (the file's 15 mm retract is the rig's; here it would only cost wall time)."""


def launch_graph(file: str, run_dir: Path, args: list[str], extra: dict[str, dict[str, Any]],
                 clock: MockClock | None = None) -> tuple[GraphHarness, dict[str, palpa.Node]]:
    """The nodes of launch ``file`` (with ``args``) and their parameters as the launcher resolves them, each node's
    parameters updated from ``extra[name]``, started in one GraphHarness."""
    plan = load_launch(REPO / file, parse_overrides(args), run_dir=run_dir)
    g = GraphHarness(clock=clock)
    nodes = {}
    for spec in plan.nodes:
        assert spec.target is not None, spec
        module, _, name = spec.target.partition(":")
        nodes[spec.name] = g.add(getattr(importlib.import_module(module), name),
                                 {**spec.params, **extra.get(spec.name, {})}, name=spec.name)
    return g, nodes


def scan_in_harness(run_dir: Path, args: list[str], timeout_s: float,
                    clock: ClockWriter | None = None) -> list[RobotPose]:
    """launch/scan_ur.yaml's graph in process until the scanner is done; returns the poses it published (at home, on
    the way, scanning). With ``clock`` (a real-time arm, the UR emulator following it: ``--clock-file``) the harness
    runs on a tests.followed_clock.FollowedClock, about as fast as the wall clock, and a stall of this process holds
    the arm too; else mock time runs at CPU speed."""
    g, nodes = launch_graph("launch/scan_ur.yaml", run_dir, [*UR_SCAN, *args], {"scanner": UR_MOVES},
                            MockClock(time.time_ns()) if clock is not None else None)
    scanner = nodes["scanner"]
    assert isinstance(scanner, RobotScanner)
    poses: list[RobotPose] = []
    deadline = time.monotonic() + timeout_s
    followed = FollowedClock(clock, g.advance) if clock is not None else None
    while not scanner.is_shutdown and time.monotonic() < deadline:
        if followed is not None:
            followed.tick()
        else:
            g.advance(0.1)
        poses += g.published("robot/pose", RobotPose)
        # stamped by the graph's clock, which the probe's samples are matched to, not by the wall's
        assert all(q.stamp_ns <= g.clock.now_ns() for q in poses[-50:])
        g.clear()
    if clock is not None:
        clock.release()  # the driver's teardown waits for the emulator: on the wall clock again
    g.close()
    assert scanner.state == "done", (scanner.state, scanner.message)
    return poses


def stiff_centre(m: Any) -> tuple[float, float]:
    """Where a map (map.npz's arrays) is stiff: the centre (mm) of its cells weighted by how far each is above the
    middle of the map's range."""
    k = m["stiffness"]
    w = np.clip(np.nan_to_num(k - (np.nanmin(k) + np.nanmax(k)) / 2, nan=0.0), 0.0, None)
    ys, xs = np.meshgrid(m["y_mm"], m["x_mm"], indexing="ij")
    return float((w * xs).sum() / w.sum()), float((w * ys).sum() / w.sum())


# whole simulated scans: each launch is bounded by its own wait (run_launch's timeout), not the suite's 120 s
pytestmark = [pytest.mark.system, pytest.mark.timeout(900)]


def run_launch(procs: ProcessGroup, run_dir: Path, file: str, *args: str, timeout: float = 240) -> str:
    p = procs.start(palpa_cmd("launch", str(REPO / file), "--run-dir", str(run_dir), "--no-progress", *args),
                    cwd=str(REPO))
    code = p.wait(timeout)
    assert code == 0, p.output()[-6000:]
    return p.output()


def inclusions(run_dir: Path) -> list[dict[str, float]]:
    return json.loads((run_dir / "map" / "inclusions.json").read_text())  # type: ignore[no-any-return]


def match(found: list[dict[str, float]], truth: list[tuple[float, float]]) -> list[float]:
    return [min(math.dist((f["x_mm"], f["y_mm"]), t) for t in truth) for f in found]


@pytest.mark.xdist_group("ur-emulator")  # real-time emulator: one at a time (make test)
@pytest.mark.timeout(150)
def test_ur_rtde_scan_through_emulator_matches_sim(tmp_path: Path) -> None:
    """launch/scan_ur.yaml's graph in process with the ur_rtde driver against the emulator (the phantom 300, -40,
    100 mm off the robot's base), then with the sim arm: the arm runs the same path in the phantom frame, and the maps
    agree cell by cell with the tumour in the same place. The graph as processes: tests/test_launch_smoke.py (sim arm)
    and tests/test_adaptive_camera_ur.py (ur_rtde); the map's accuracy against the truth: the sim-arm scans."""
    home = [h + o for h, o in zip((39.0, 12.0, 9.0), UR_OFFSET, strict=True)]
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--home", ",".join(map(str, [*home, 0, math.pi, 0])),
                          "--clock-file", str(writer.path)]) as emu:
            ur = scan_in_harness(tmp_path / "ur", [f"robot_host:={emu.host}"], timeout_s=60, clock=writer)
    finally:
        writer.close()
    sim = scan_in_harness(tmp_path / "sim", ["scanner_driver:=sim"], timeout_s=60)
    # the same path: every pose the UR reported lies on the sim arm's (sampled every 0.16 mm at most)
    a = np.array([(q.x_mm, q.y_mm, q.z_mm) for q in ur])
    b = np.array([(q.x_mm, q.y_mm, q.z_mm) for q in sim])
    off_path = cKDTree(b).query(a)[0]
    assert len(a) > 500 and off_path.max() < 0.15, (len(a), off_path.max())
    assert np.ptp(a[:, 0]) == pytest.approx(12.0, abs=0.01) and np.ptp(a[:, 1]) == pytest.approx(12.0, abs=0.01)
    ma, mb = np.load(tmp_path / "ur" / "map" / "map.npz"), np.load(tmp_path / "sim" / "map" / "map.npz")
    fa, fb = np.isfinite(ma["stiffness"]), np.isfinite(mb["stiffness"])
    both = fa & fb
    assert both.sum() >= 25 and both.sum() >= 0.8 * max(fa.sum(), fb.sum()), (both.sum(), fa.sum(), fb.sum())
    rel = np.abs(ma["stiffness"][both] / mb["stiffness"][both] - 1)
    assert np.median(rel) < 0.02, np.median(rel)
    # the tumour in the same place (the UR's and the sim's maps agree more closely than either with the truth). The
    # UR run is on the wall clock: which probe sample meets which pose, and so the noise in each 2 mm cell, differs
    # from run to run; its stiff centre moved by up to 0.61 mm from the sim's over the runs seen (half a cell allowed)
    ca, cb = stiff_centre(ma), stiff_centre(mb)
    assert math.dist(ca, cb) < 1.0 and math.dist(cb, (45.0, 18.0)) < 1.5, (ca, cb)


def test_airfloat_scan_finds_the_tumours_and_its_recording_replays(procs: ProcessGroup, tmp_path: Path,
                                                                    calibration: Path) -> None:
    """`make demo`'s scan (launch/scan_sim.yaml, defaults, calibrated probe) over a 24 mm square around the r 5 x4
    tumour, scored against the truth: found within 1.5 mm, no false positive, healthy cells called healthy; the
    recording replayed into a live estimator and map aggregator (launch/replay_scan.yaml) gives the same map. The
    whole phantom (the r 6 x6 found too; the honest world hides the r 4 x2 and r 3 x3 ones at these settings) is
    `make demo`'s, with its figures in BENCHMARKS.md."""
    from models.scoring import score_scan

    run = tmp_path / "scan"
    # composed in one process (issue 16): the same nodes, topics, recording and outputs as one process per node,
    # at CPU speed; tests/test_launch_smoke.py runs the file as processes. The region holds the weaker of the two
    # large tumours with healthy tissue on every side of it (a region holding both large tumours, [6, 6, 54, 30],
    # puts this one 2.7 mm off: the map's baseline and the touch-off's surface fit depend on the region; the whole
    # phantom puts it 1.4 mm off, most of it from the measured thickness's error there, BENCHMARKS.md)
    region = (30.0, 6.0, 54.0, 30.0)
    run_launch(procs, run, "launch/scan_sim.yaml", "--in-process", f"calibration:={calibration}",
               f"region_mm:={list(region)}", timeout=400)
    for name in ("map.npz", "map.png", "inclusions.json"):
        assert (run / "map" / name).stat().st_size > 0
    assert (run / "recording.mcap").stat().st_size > 100_000
    with np.load(run / "map" / "map.npz") as grid:
        score = score_scan(load_phantom(REPO / "phantoms" / "airfloat_tumours.yaml"), inclusions(run), grid)
    inside = [s for s in score.inclusions if region[0] < s.center_mm[0] < region[2] and
              region[1] < s.center_mm[1] < region[3]]
    assert [s.radius_mm for s in inside] == [5.0]
    assert all(s.found and s.centroid_error_mm <= 1.5 for s in inside), score.summary()
    assert not score.false_positives and score.specificity > 0.95, score.summary()

    replay = tmp_path / "replay"
    run_launch(procs, replay, "launch/replay_scan.yaml", f"bag:={run / 'recording.mcap'}", "rate:=4.0",
               f"calibration:={calibration}", timeout=300)
    a, b = np.load(run / "map" / "map.npz"), np.load(replay / "map" / "map.npz")
    fa_, fb_ = np.isfinite(a["stiffness"]), np.isfinite(b["stiffness"])
    # a sparse edge cell (at the minimum sample count) may tip either way: a handful of samples near the start
    # and end of the recording are timed differently on replay
    assert (fa_ != fb_).sum() <= 0.02 * fa_.sum()
    both = fa_ & fb_
    assert np.abs(a["stiffness"][both] / b["stiffness"][both] - 1).max() < 0.02
    assert abs(int(a["count"].sum()) - int(b["count"].sum())) < 0.02 * a["count"].sum()
    fa, fb = inclusions(run), inclusions(replay)
    assert len(fa) == len(fb)
    for x, y in zip(fa, fb, strict=True):
        assert math.dist((x["x_mm"], x["y_mm"]), (y["x_mm"], y["y_mm"])) < 0.2


@pytest.mark.parametrize("phantom", ["flat_26k.yaml", "flat_10k.yaml"])
def test_no_inclusion_on_a_flat_phantom(phantom: str, tmp_path: Path, calibration: Path) -> None:
    """The same nodes in-process (mock clock), realistic calibrated probe: a phantom without inclusions gives no
    detection at all, and the map's median is within 6 % of the truth."""
    from nodes.mapping.map_aggregator import MapAggregator
    from nodes.probe.fibre_reader import FibreReader
    from nodes.probe.pressure_controller import PressureController
    from nodes.probe.stiffness_estimator import AirfloatStiffnessEstimator
    from nodes.scanner.robot_scanner import RobotScanner
    from palpa.testing import GraphHarness

    path = str(REPO / "phantoms" / phantom)
    g = GraphHarness()
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 34.0, "calibration": str(calibration)})
    g.add(FibreReader, {"phantom": path})
    g.add(AirfloatStiffnessEstimator, {"geometry": str(REPO / "phantoms" / "measured" / phantom),
                                       "calibration": str(calibration)})
    g.add(MapAggregator, {"output_dir": str(tmp_path)})
    scanner = g.add(RobotScanner, {"region_mm": [15, 15, 45, 45], "spacing_mm": 5.0, "speed_mm_s": 40.0,
                                   "contact_z_mm": 21.0, "home_mm": [15, 15, 30]})
    while not scanner.is_shutdown:
        g.advance(1.0)
        g.clear()
    g.close()
    assert scanner.exit_code == 0
    assert json.loads((tmp_path / "inclusions.json").read_text()) == []
    grid = np.load(tmp_path / "map.npz")["stiffness"]
    truth = load_phantom(path).youngs_modulus_kpa
    assert abs(np.nanmedian(grid) / truth - 1) < 0.06


def test_camera_probe_indent_scan_finds_the_tumours(procs: ProcessGroup, tmp_path: Path) -> None:
    """launch/scan_camera_sim.yaml: the camera probe's indentation scan of flat_26k_tumours finds every inclusion
    of radius >= 4 mm and ratio >= 2 in its region within 1.5 mm, with at most one false positive."""
    run = tmp_path / "cam"
    # a 20 mm square around the weakest tumour (r 4, x2: the hardest to find), centred on it so that the 4 mm grid
    # samples it symmetrically, with healthy tissue on every side for the map's baseline; bench/specimens.py scans
    # whole phantoms
    region = (18.0, 34.0, 38.0, 54.0)
    run_launch(procs, run, "launch/scan_camera_sim.yaml", "--in-process", f"region_mm:={list(region)}",
               timeout=400)
    phantom = load_phantom(REPO / "phantoms" / "flat_26k_tumours.yaml")
    found = inclusions(run)
    must = [i for i in phantom.inclusions if i.radius_mm >= 4 and (i.youngs_modulus_kpa or 0.0) / 26.4 >= 2
            and region[0] < i.center_mm[0] < region[2] and region[1] < i.center_mm[1] < region[3]]
    assert len(must) == 1
    for inc in must:
        assert min(math.dist((f["x_mm"], f["y_mm"]), inc.center_mm) for f in found) <= 1.5, (inc, found)
    assert len(match(found, [i.center_mm for i in phantom.inclusions])) - sum(
        e <= 3.0 for e in match(found, [i.center_mm for i in phantom.inclusions])) <= 1
