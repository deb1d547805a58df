"""Table I of the camera-probe paper through rendered frames -> tracker -> estimator, before and after calibration.

    nice python -m bench.table_i [--probes 7 11] [--poses all|flat] [--out table_i.json]

For each simulated probe (``device_seed``: its springs, marker scales, friction and lens as built): calibrate it on
the rigid flat and reference springs (tools/camera_calibrate.py), then press every Table I spring sample once at
each inclination (pan, tilt) in POSES_DEG, 8 mm deep at 3 mm/s with a 1.5 s hold, in-process (GraphHarness), with
the nominal probe constants (before) and with the calibration file (after). Per spring (inclinations pooled) and
per press: mean K over the valid samples, sigma, RMSE and two accuracies:

- ``rel``: 100 (1 - |K_mean - K| / K), the relative error (what we report and what the acceptance uses);
- ``paper``: 100 (1 - |K_mean - K| / (1 N/mm)), which reproduces the paper's column on three of its four rows.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from messages import StiffnessSample
from nodes.probe.camera_tracker import CameraTracker
from nodes.probe.stiffness_estimator import MultiIndenterStiffnessEstimator
from nodes.scanner.linear_stage import LinearStage
from palpa.testing import GraphHarness
from tools.camera_calibrate import REFERENCES, calibrate, press_reference

SPRINGS = {0.29: "phantoms/springs_029.yaml", 0.37: "phantoms/springs_037.yaml",
           0.62: "phantoms/springs_062.yaml", 0.63: "phantoms/springs_063.yaml"}
PAPER_TABLE_I = {0.29: (0.2908, 0.012, 0.0101, 99.2393), 0.37: (0.3812, 0.0013, 0.0113, 98.8781),
                 0.62: (0.6545, 0.0346, 0.0489, 96.5466), 0.63: (0.6674, 0.0155, 0.045, 96.2610)}
POSES_DEG = ((0.0, 0.0), (0.0, 15.0), (15.0, 0.0), (10.6, -10.6))  # (pan, tilt); the last: 14.8° of inclination


def press_once(k: float, pan: float, tilt: float, *, device_seed: int, seed: int, calibration_file: str = "",
               depth_mm: float = 8.0, hold_s: float = 1.5, speed_mm_s: float = 3.0,
               spread: str = "normal") -> list[StiffnessSample]:
    """One ramp-hold-release press of the linear stage into a spring sample; every stiffness sample."""
    g = GraphHarness()
    g.add(LinearStage, {"phantom": SPRINGS[k], "depth_mm": depth_mm, "speed_mm_s": speed_mm_s, "hold_s": hold_s,
                        "settle_s": 1.2, "dwell_s": 0.0})
    g.add(CameraTracker, {"phantom": SPRINGS[k], "pan_deg": pan, "tilt_deg": tilt, "seed": seed,
                          "device_seed": device_seed, "calibration_file": calibration_file, "tolerance_spread": spread})
    g.add(MultiIndenterStiffnessEstimator, {"min_displacement_mm": 1.0,
                                            "calibration_file": calibration_file})
    g.advance(1.2 + 2 * (depth_mm + 4.0) / speed_mm_s + hold_s + 0.3)
    samples: list[StiffnessSample] = g.published("stiffness/sample", StiffnessSample)
    g.close()
    return samples


def accuracy(k: float, values: np.ndarray) -> dict[str, float]:
    """K_mean, sigma, RMSE and both accuracies (%) of ``values`` against the true K."""
    mean = float(values.mean())
    return {"n": int(values.size), "mean": mean, "sd": float(values.std()),
            "rmse": float(np.sqrt(np.mean((values - k) ** 2))), "rel": 100.0 * (1 - abs(mean - k) / k),
            "paper": 100.0 * (1 - abs(mean - k))}


def calibrate_probe(device_seed: int, path: Path) -> dict[str, object]:
    """Run the calibration procedure on the simulated probe and write its file."""
    presses = [(press_reference(p, device_seed=device_seed, seed=1000 + 10 * device_seed + i, depth_mm=d,
                                speed_mm_s=v), kr) for i, (p, kr, d, v) in enumerate(REFERENCES)]
    cal = calibrate(presses, {"device_seed": device_seed})
    path.write_text(yaml.safe_dump(cal.to_dict(), sort_keys=False))
    return cal.to_dict()


def table(device_seed: int, calibration_file: str, poses: tuple[tuple[float, float], ...]) -> dict[str, object]:
    """Table I for one probe with (or without) a calibration file: per spring pooled and per press."""
    rows, presses = {}, []
    for i, k in enumerate(SPRINGS):
        pooled = []
        for j, (pan, tilt) in enumerate(poses):
            valid = [s for s in press_once(k, pan, tilt, device_seed=device_seed, seed=10 * i + j,
                                           calibration_file=calibration_file) if s.valid]
            values = np.array([s.value for s in valid])
            pooled.append(values)
            row: dict[str, float] = accuracy(k, values) if values.size else {"n": 0}
            if valid:
                row["pan_err_deg"] = math.degrees(float(np.mean([s.pan_rad for s in valid]))) - pan
                row["tilt_err_deg"] = math.degrees(float(np.mean([s.tilt_rad for s in valid]))) - tilt
            presses.append({"k": k, "pan": pan, "tilt": tilt, **row})
        rows[str(k)] = accuracy(k, np.concatenate(pooled))
    return {"springs": rows, "presses": presses}


def survey(probes: int, spread: str) -> dict[str, list[float]]:
    """Accuracy (rel %) of each spring before calibration, flat press, over ``probes`` simulated probes."""
    out: dict[str, list[float]] = {str(k): [] for k in SPRINGS}
    for probe in range(probes):
        for i, k in enumerate(SPRINGS):
            values = np.array([s.value for s in press_once(k, 0.0, 0.0, device_seed=probe, seed=i, spread=spread)
                               if s.valid])
            out[str(k)].append(accuracy(k, values)["rel"] if values.size else math.nan)
    return out


def _print(title: str, result: dict[str, object]) -> None:
    print(f"\n{title}\n| K | paper K̄ | paper acc. | K̄ | σ | RMSE | acc. rel % | acc. paper's formula % |")
    springs = result["springs"]
    assert isinstance(springs, dict)
    for k, r in springs.items():
        p = PAPER_TABLE_I[float(k)]
        print(f"| {k} | {p[0]:.4f} | {p[3]:.2f} | {r['mean']:.4f} | {r['sd']:.4f} | {r['rmse']:.4f} | "
              f"{r['rel']:.2f} | {r['paper']:.2f} |")
    print("per press:   K    pan   tilt     n   mean K   rel %  pan err tilt err")
    presses = result["presses"]
    assert isinstance(presses, list)
    for r in presses:
        if r["n"]:
            print(f"         {r['k']:5.2f} {r['pan']:6.1f} {r['tilt']:6.1f} {r['n']:5d} {r['mean']:8.4f} "
                  f"{r['rel']:7.2f} {r['pan_err_deg']:+7.2f} {r['tilt_err_deg']:+7.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--probes", type=int, nargs="+", default=[7], help="probe seeds (one simulated probe each)")
    ap.add_argument("--poses", choices=("all", "flat"), default="all")
    ap.add_argument("--out", default="", help="write every figure as JSON here")
    ap.add_argument("--survey", type=int, default=0, help="instead: before-calibration accuracy of N probes, flat")
    ap.add_argument("--spread", choices=("normal", "uniform"), default="normal", help="tolerance spread (survey)")
    args = ap.parse_args()
    if args.survey:
        res = survey(args.survey, args.spread)
        every = np.array(list(res.values()))
        print(f"{args.survey} probes, tolerances spread {args.spread}: accuracy before calibration (rel %)")
        for k, acc in res.items():
            a = np.array(acc)
            print(f"  K {k}: median {np.median(a):.2f}, 10-90 % {np.percentile(a, 10):.2f}-{np.percentile(a, 90):.2f},"
                  f" min {a.min():.2f}, max {a.max():.2f}")
        inside = np.mean(np.all((every >= 94.0) & (every <= 99.9), axis=0))
        print(f"  probes with every spring in 94-99.9 %: {100 * inside:.0f} %")
        if args.out:
            Path(args.out).write_text(json.dumps(res))
        return
    poses = POSES_DEG if args.poses == "all" else POSES_DEG[:1]
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for probe in args.probes:
            t0 = time.process_time()
            path = Path(tmp) / f"probe{probe}.yaml"
            cal = calibrate_probe(probe, path)
            before = table(probe, "", poses)
            after = table(probe, str(path), poses)
            cpu = time.process_time() - t0
            _print(f"probe {probe}: before calibration (nominal springs and scale)", before)
            _print(f"probe {probe}: after calibration", after)
            print(f"probe {probe}: calibrated springs {cal['k_n_per_mm']}; CPU {cpu:.0f} s")
            out[str(probe)] = {"calibration": cal, "before": before, "after": after, "cpu_s": cpu}
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
