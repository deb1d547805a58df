"""The batch evaluation runner and the random phantom generator (issue 16)."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest

from messages import RobotPose, ScanStatus, StiffnessSample
from models.phantom import load_phantom, parse_phantom
from models.phantom_gen import PhantomRanges, random_phantom
from palpa.record.testing import Rec, write_bag
from tools.evaluate import RunSpec, scan_facts, score_outputs, score_run, summarize

REPO = Path(__file__).resolve().parent.parent


def test_random_phantoms_are_seeded_valid_and_keep_inclusions_apart() -> None:
    r = PhantomRanges(inclusions=(3, 6), dome_probability=0.5)
    assert random_phantom(7, r) == random_phantom(7, r)
    assert random_phantom(7, r) != random_phantom(8, r)
    domed = 0
    for seed in range(40):
        data = random_phantom(seed, r)
        ph = parse_phantom(data, f"seed {seed}")  # the phantom model's own validation
        domed += isinstance(data["thickness_mm"], dict)
        lo_t = min(data["thickness_mm"].values()) if isinstance(data["thickness_mm"], dict) else data["thickness_mm"]
        w, h = ph.size_mm
        for i, a in enumerate(ph.inclusions):
            x, y = a.center_mm
            assert r.margin_mm + a.radius_mm <= x <= w - r.margin_mm - a.radius_mm
            assert r.margin_mm + a.radius_mm <= y <= h - r.margin_mm - a.radius_mm
            assert a.depth_mm < lo_t  # under the surface even at a dome's thin edge
            for b in ph.inclusions[i + 1:]:
                assert math.dist(a.center_mm, b.center_mm) >= a.radius_mm + b.radius_mm + r.margin_mm
            ratio = a.youngs_modulus_kpa / ph.youngs_modulus_kpa
            assert r.ratio[0] - 0.01 <= ratio <= r.ratio[1] + 0.01
    assert 5 < domed < 35  # both kinds of top are drawn


def test_bad_ranges_are_refused_with_the_field_named() -> None:
    with pytest.raises(ValueError, match="radius_mm"):
        PhantomRanges(radius_mm=(5.0, 2.0))


def _fake_run(tmp: Path) -> RunSpec:
    """A run directory as a launch leaves it: one detection 0.5 mm off the truth plus a false one, a map whose
    cells are stiff over the true inclusion, and a recording of a 10 s scan along 30 mm with 4 valid samples."""
    phantom = tmp / "ph.yaml"
    phantom.write_text("size_mm: [40, 40]\nthickness_mm: 5\nyoungs_modulus_kpa: 20\npoisson_ratio: 0.5\n"
                       "inclusions: [{center_mm: [20, 20], radius_mm: 5, depth_mm: 1, youngs_modulus_kpa: 80}]\n")
    out = tmp / "run" / "map"
    out.mkdir(parents=True)
    (out / "inclusions.json").write_text(json.dumps([
        {"x_mm": 20.5, "y_mm": 20.0, "radius_mm": 5.0, "contrast": 3.0},
        {"x_mm": 5.0, "y_mm": 35.0, "radius_mm": 2.0, "contrast": 1.5}]))
    axis = np.arange(1.0, 40.0, 2.0)
    yy, xx = np.meshgrid(axis, axis, indexing="ij")
    stiff = np.where(np.hypot(xx - 20, yy - 20) <= 5, 80.0, 20.0)
    np.savez(out / "map.npz", stiffness=stiff, x_mm=axis, y_mm=axis, count=np.full(stiff.shape, 5))
    t0 = 1_700_000_000_000_000_000
    enc = msgspec.msgpack.encode
    recs = [Rec("robot/scan_status", t0, enc(ScanStatus(stamp_ns=t0, state="waiting", line=0, lines=1, progress=0,
                                                           eta_s=0)), 1, "ScanStatus", "scanner"),
            Rec("robot/scan_status", t0 + 1, enc(ScanStatus(stamp_ns=t0 + 1, state="scanning", line=0, lines=1,
                                                               progress=0, eta_s=0)), 2, "ScanStatus", "scanner")]
    for i, y in enumerate([0.0, 10.0, 30.0]):  # 30 mm while scanning
        t = t0 + 1 + i * 4_000_000_000
        recs.append(Rec("robot/pose", t, enc(RobotPose(stamp_ns=t, x_mm=10.0, y_mm=y, z_mm=5.0)), i + 1,
                        "RobotPose", "scanner"))
    for i in range(6):
        t = t0 + 2 + i
        recs.append(Rec("stiffness/sample", t, enc(StiffnessSample(
            stamp_ns=t, model="airfloat", x_mm=1, y_mm=1, z_mm=1, value=20, unit="kPa", valid=i < 4, reason="")),
            i + 1, "StiffnessSample", "estimator"))
    done = t0 + 10_000_000_001
    recs.append(Rec("robot/scan_status", done, enc(ScanStatus(stamp_ns=done, state="done", line=1, lines=1,
                                                               progress=1, eta_s=0)), 3, "ScanStatus", "scanner"))
    recs.append(Rec("robot/pose", done + 1, enc(RobotPose(stamp_ns=done + 1, x_mm=10.0, y_mm=90.0, z_mm=5.0)), 9,
                    "RobotPose", "scanner"))  # after the scan: not path
    write_bag(tmp / "run" / "recording.mcap", recs)
    return RunSpec("r0", phantom, 0, {"spacing_mm": 3}, run_dir=tmp / "run")


def test_an_adaptive_runs_path_starts_at_its_first_probe_not_at_its_touch_off(tmp_path: Path) -> None:
    """The raster's span starts when it is 'scanning', the adaptive planner's when the scanner is first 'probing':
    the touch-off before either is neither method's path (issue 41's path_ratio compares like with like)."""
    t0 = 1_700_000_000_000_000_000
    enc = msgspec.msgpack.encode

    def status(t: int, state: str, seq: int) -> Rec:
        return Rec("robot/scan_status", t, enc(ScanStatus(stamp_ns=t, state=state, line=0, lines=0, progress=0,
                                                           eta_s=0)), seq, "ScanStatus", "scanner")

    def pose(t: int, y: float, seq: int) -> Rec:
        return Rec("robot/pose", t, enc(RobotPose(stamp_ns=t, x_mm=10.0, y_mm=y, z_mm=5.0)), seq, "RobotPose",
                   "scanner")

    recs = [status(t0, "touching", 1), pose(t0 + 1, 0.0, 1), pose(t0 + 2, 50.0, 2),   # 50 mm of touch-off
            status(t0 + 3, "probing", 2), pose(t0 + 4, 56.0, 3), status(t0 + 5, "idle", 3), pose(t0 + 6, 60.0, 4)]
    write_bag(tmp_path / "recording.mcap", recs)
    assert scan_facts(tmp_path / "recording.mcap")["path_mm"] == pytest.approx(4.0)   # poses from 'probing' on: 56 -> 60


def test_a_run_is_scored_against_its_phantom_and_its_recording(tmp_path: Path) -> None:
    spec = _fake_run(tmp_path)
    facts = scan_facts(spec.run_dir / "recording.mcap")
    assert facts["scan_s"] == pytest.approx(10.0)
    assert facts["path_mm"] == pytest.approx(30.0)
    assert facts["probes"] == 4
    row, incs = score_run(spec, load_phantom(spec.phantom))
    assert (row["true_inclusions"], row["found"], row["missed"], row["false_positives"]) == (1, 1, 0, 1)
    assert row["mean_centroid_error_mm"] == pytest.approx(0.5)
    assert row["sensitivity"] > 0.9 and 0.9 < row["specificity"] < 1.0  # the false detection's cells
    assert incs == [{"run": "r0", "inclusion": 0, "radius_mm": 5.0, "ratio": 4.0, "depth_mm": 1.0, "found": True,
                     "centroid_error_mm": pytest.approx(0.5), "radius_error_mm": pytest.approx(0.0)}]
    # the detections: the first matched the true inclusion, the second matched nothing
    assert score_outputs(spec, load_phantom(spec.phantom))[2] == [
        {"run": "r0", "detection": 0, "x_mm": 20.5, "y_mm": 20.0, "radius_mm": 5.0, "contrast": 3.0, "inclusion": 0},
        {"run": "r0", "detection": 1, "x_mm": 5.0, "y_mm": 35.0, "radius_mm": 2.0, "contrast": 1.5, "inclusion": -1}]
    lines = summarize([{**row, "run": "r0", "spacing_mm": 3, "error": ""},
                       {"run": "r1", "spacing_mm": 3, "error": "launch failed"}], ["spacing_mm"])
    assert len(lines) == 1
    assert lines[0].startswith("spacing_mm=3: 1 of 2 runs scored; inclusions found 1/1 (100 %); false positives 1")


def test_two_equal_detections_of_one_inclusion_are_one_match_and_one_false_positive(tmp_path: Path) -> None:
    spec = _fake_run(tmp_path)
    twice = {"x_mm": 20.5, "y_mm": 20.0, "radius_mm": 5.0, "contrast": 3.0}
    (spec.run_dir / "map" / "inclusions.json").write_text(json.dumps([twice, twice]))
    row, _, dets = score_outputs(spec, load_phantom(spec.phantom))
    assert row["false_positives"] == 1 and [d["inclusion"] for d in dets] == [0, -1]


@pytest.mark.timeout(300)
@pytest.mark.system
def test_evaluate_runs_a_generated_phantom_end_to_end(tmp_path: Path) -> None:
    """`python -m tools.evaluate` on one generated phantom, a small raster: tables and a summary."""
    out = tmp_path / "eval"
    proc = subprocess.run(
        [sys.executable, "-m", "tools.evaluate", str(REPO / "launch" / "scan_sim.yaml"), "--generate", "1",
         "--phantom-seed", "3", "--jobs", "1", "-o", str(out), "--arg", "region_mm=[[8.0, 24.0, 20.0, 36.0]]",
         "--arg", "spacing_mm=4.0"], capture_output=True, text=True, timeout=280, cwd=REPO)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    rows = list(csv.DictReader((out / "runs.csv").open()))
    assert [r["run"] for r in rows] == ["random_3-s0"] and rows[0]["error"] == ""
    assert int(rows[0]["true_inclusions"]) == 1 and float(rows[0]["probes"]) > 100
    assert float(rows[0]["scan_s"]) > 5 and float(rows[0]["path_mm"]) > 40
    assert (out / "summary.txt").read_text().startswith("region_mm=[8.0, 24.0, 20.0, 36.0], spacing_mm=4.0: 1 of 1")
    assert json.loads((out / "runs.json").read_text())[0]["run"] == "random_3-s0"


def test_evaluate_redetect_scores_the_runs_left_in_out_with_the_map_detector(tmp_path: Path) -> None:
    """``--redetect`` launches nothing: it plans the sweep's runs as a launch would, runs models.detector on each
    run's map.npz again (its stale inclusions.json is ignored) and writes the tables from those detections; a run
    with no map in OUT is an error row and the exit code 1."""
    from tools.evaluate import main

    spec = _fake_run(tmp_path)
    out = tmp_path / "eval"
    run_dir = out / "runs" / "ph-s0"  # where the sweep put the run of phantom ph.yaml, seed 0
    run_dir.parent.mkdir(parents=True)
    spec.run_dir.rename(run_dir)
    # the map: a noisy background with one disc of the phantom's inclusion three times stiffer; the run's own
    # inclusions.json names two wrong places (an older detector's)
    rng = np.random.default_rng(3)
    axis = np.arange(1.0, 40.0, 2.0)
    yy, xx = np.meshgrid(axis, axis, indexing="ij")
    stiff = 20.0 * np.exp(0.03 * rng.standard_normal(xx.shape)) * np.where(np.hypot(xx - 20, yy - 20) <= 5, 3.0, 1.0)
    np.savez(run_dir / "map" / "map.npz", stiffness=stiff, x_mm=axis, y_mm=axis, count=np.full(stiff.shape, 5))
    (run_dir / "map" / "inclusions.json").write_text(json.dumps([
        {"x_mm": 5.0, "y_mm": 35.0, "radius_mm": 2.0, "contrast": 1.5},
        {"x_mm": 35.0, "y_mm": 5.0, "radius_mm": 2.0, "contrast": 1.5}]))
    launch = str(REPO / "launch" / "scan_sim.yaml")
    assert main([launch, "--phantom", str(spec.phantom), "--seeds", "0", "-o", str(out), "--redetect"]) == 0
    runs = list(csv.DictReader((out / "runs.csv").open()))
    assert [(r["run"], r["error"], r["found"], r["false_positives"]) for r in runs] == [("ph-s0", "", "1", "0")]
    assert float(runs[0]["probes"]) == 4  # the run's recording read as a launched run's
    dets = list(csv.DictReader((out / "detections.csv").open()))
    assert len(dets) == 1 and dets[0]["inclusion"] == "0"
    assert math.hypot(float(dets[0]["x_mm"]) - 20, float(dets[0]["y_mm"]) - 20) < 1.0
    assert json.loads((run_dir / "map" / "inclusions.json").read_text())[0]["x_mm"] == 5.0  # the run is read only
    # seed 1 was never run: nothing is launched for it, its row says why, and the sweep fails
    assert main([launch, "--phantom", str(spec.phantom), "--seeds", "0", "1", "-o", str(out), "--redetect"]) == 1
    runs = list(csv.DictReader((out / "runs.csv").open()))
    assert [r["run"] for r in runs] == ["ph-s0", "ph-s1"]
    assert runs[0]["found"] == "1" and runs[1]["error"].startswith("cannot score") and not (out / "runs" / "ph-s1").exists()
    # a map its node wrote as partial (the scan stopped) is no result, however well it detects
    np.savez(run_dir / "map" / "map.npz", stiffness=stiff, x_mm=axis, y_mm=axis, count=np.full(stiff.shape, 5),
             incomplete=np.array("the scan did not finish: last heard scanning at 14 % of its path"))
    assert main([launch, "--phantom", str(spec.phantom), "--seeds", "0", "-o", str(out), "--redetect"]) == 1
    runs = list(csv.DictReader((out / "runs.csv").open()))
    assert runs[0]["error"] == "the map is INCOMPLETE: the scan did not finish: last heard scanning at 14 % of its path"


def test_generated_blank_phantoms_are_the_random_ones_without_their_inclusions(tmp_path: Path) -> None:
    """--generate N --blank: each blank_SEED is random_SEED's specimen with no inclusion (a false-alarm check on the
    same varied specimens the sets are judged on); without --blank the files are the generator's as before."""
    from tools.evaluate import generate_phantoms

    blank = generate_phantoms(tmp_path / "b", 30000, 3, blank=True)
    rand = generate_phantoms(tmp_path / "r", 30000, 3)
    assert [p.name for p in blank] == [f"blank_{s}.yaml" for s in range(30000, 30003)]
    assert [p.name for p in rand] == [f"random_{s}.yaml" for s in range(30000, 30003)]
    with_inclusions = 0
    for b, r, seed in zip(blank, rand, range(30000, 30003), strict=True):
        pb, pr = load_phantom(b), load_phantom(r)
        assert pb.inclusions == ()
        assert (pb.size_mm, pb.thickness_mm, pb.youngs_modulus_kpa) == (pr.size_mm, pr.thickness_mm,
                                                                          pr.youngs_modulus_kpa)
        assert parse_phantom(random_phantom(seed, PhantomRanges()), "x") == pr
        with_inclusions += len(pr.inclusions) > 0
    assert with_inclusions   # the comparison is not between two blank sets


def test_blank_without_generate_is_refused_before_anything_is_written(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    from tools.evaluate import main

    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main([str(REPO / "launch" / "scan_sim.yaml"), "--phantom", str(REPO / "phantoms" / "airfloat_tumours.yaml"),
              "--blank", "-o", str(out)])
    assert exc.value.code == 2
    assert "--blank makes the generated phantoms blank: give --generate N" in capsys.readouterr().err
    assert not out.exists()
