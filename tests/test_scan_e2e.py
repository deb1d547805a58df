"""The product's main job end to end (issues 8 and 9): scans that find the tumours, with the sim arm and with
the ur_rtde driver through the UR emulator, and a recording that replays into the same map."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from emulators.ur.process import UrEmulatorProcess
from models.phantom import load_phantom
from tests.procs import ProcessGroup, palpa_cmd
from tests.test_launch_smoke import REPO

SMALL_UR = ["fibre_driver:=sim", "pressure_driver:=sim", "phantom:=phantoms/airfloat_tumours.yaml", "region_mm:=[30.0, 6.0, 54.0, 30.0]", "spacing_mm:=3.0",
            "speed_mm_s:=20.0", "home_mm:=[30.0, 6.0, 20.0]",
            # wall-clock graphs on a loaded 2-core CI machine: the rig default (0.1 s) is tested in test_robot_scanner
            "watchdog_s:=0.5"]


# whole simulated scans: each launch is bounded by its own wait (run_launch's timeout), not the suite's 120 s
pytestmark = pytest.mark.timeout(900)


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


def test_ur_rtde_scan_through_emulator_matches_sim(procs: ProcessGroup, tmp_path: Path) -> None:
    """launch/scan_ur.yaml with the ur_rtde driver against the emulator, then with the sim arm: same map."""
    emu = UrEmulatorProcess.on_random_loopback(["--home", "30,6,20,0,3.141592653589793,0"])
    emu.start()
    try:
        run_launch(procs, tmp_path / "ur", "launch/scan_ur.yaml", f"robot_host:={emu.host}", *SMALL_UR)
    finally:
        emu.stop()
    run_launch(procs, tmp_path / "sim", "launch/scan_ur.yaml", "scanner_driver:=sim", *SMALL_UR)
    a = np.load(tmp_path / "ur" / "map" / "map.npz")
    b = np.load(tmp_path / "sim" / "map" / "map.npz")
    both = np.isfinite(a["stiffness"]) & np.isfinite(b["stiffness"])
    assert both.sum() >= 0.8 * max(np.isfinite(a["stiffness"]).sum(), np.isfinite(b["stiffness"]).sum())
    rel = np.abs(a["stiffness"][both] / b["stiffness"][both] - 1)
    assert np.median(rel) < 0.02 and rel.max() < 0.15
    ia, ib = inclusions(tmp_path / "ur"), inclusions(tmp_path / "sim")
    assert len(ia) == len(ib) == 1
    # each run draws its own sensor noise, regulator wander and hysteresis on its own timing (the honest world):
    # the two maps agree cell by cell (above), their centroids within a mm, and each is within 1.5 mm of the truth
    assert math.dist((ia[0]["x_mm"], ia[0]["y_mm"]), (ib[0]["x_mm"], ib[0]["y_mm"])) < 1.0
    assert math.dist((ia[0]["x_mm"], ia[0]["y_mm"]), (45.0, 18.0)) < 1.5


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
    # at CPU speed; tests/test_launch_smoke.py runs the file as processes. The region is the one the UR test scans
    # (SMALL_UR): the weaker of the two large tumours with healthy tissue on every side of it (a region holding
    # both large tumours, [6, 6, 54, 30], puts this one 2.7 mm off: the map's baseline and the touch-off's surface
    # fit depend on the region; the whole phantom puts it 1.4 mm off, BENCHMARKS.md)
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
    from nodes.fibre_reader import FibreReader
    from nodes.map_aggregator import MapAggregator
    from nodes.pressure_controller import PressureController
    from nodes.robot_scanner import RobotScanner
    from nodes.stiffness_estimator import AirfloatStiffnessEstimator
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
    must = [i for i in phantom.inclusions if i.radius_mm >= 4 and i.youngs_modulus_kpa / 26.4 >= 2
            and region[0] < i.center_mm[0] < region[2] and region[1] < i.center_mm[1] < region[3]]
    assert len(must) == 1
    for inc in must:
        assert min(math.dist((f["x_mm"], f["y_mm"]), inc.center_mm) for f in found) <= 1.5, (inc, found)
    assert len(match(found, [i.center_mm for i in phantom.inclusions])) - sum(
        e <= 3.0 for e in match(found, [i.center_mm for i in phantom.inclusions])) <= 1
