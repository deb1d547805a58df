"""What a wrong thickness does to the air-float map: replay one recorded scan with measured-geometry files biased
by -1, -0.5, 0, +0.5 and +1 mm (each also carrying the 0.2 mm per-point scatter of the shipped file).

The recording's heights, pressure and pose go through ``launch/replay_scan.yaml`` (a live estimator and map
aggregator) once per geometry; each map is scored against the phantom (models/scoring.py). Prints a table and one
JSON line.

    .venv/bin/python bench/airfloat_thickness.py RUN_DIR [--calibration FILE] [--phantom phantoms/airfloat_tumours.yaml]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.geometry import measure_phantom  # noqa: E402
from models.phantom import load_phantom  # noqa: E402
from models.scoring import score_scan  # noqa: E402
from models.stiffness_map import background  # noqa: E402

BIASES = [-1.0, -0.5, 0.0, 0.5, 1.0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path, help="a finished scan_sim run (with recording.mcap)")
    ap.add_argument("--phantom", type=Path, default=REPO / "phantoms" / "airfloat_tumours.yaml")
    ap.add_argument("--calibration", type=Path, help="the calibration the scan used (default RUN_DIR/calibration.yaml)")
    ap.add_argument("--out", type=Path, default=Path("runs/thickness-study"))
    args = ap.parse_args()
    ph = load_phantom(args.phantom)
    cal = args.calibration or (args.run_dir / "calibration.yaml")
    t0 = time.perf_counter()
    rows = []
    for bias in BIASES:
        out = args.out / f"bias{bias:+.1f}"
        out.mkdir(parents=True, exist_ok=True)
        geo = out / "geometry.yaml"
        geo.write_text(yaml.safe_dump(measure_phantom(ph, error_mm=0.2, bias_mm=bias, seed=0).to_yaml_data(),
                                      default_flow_style=None))
        cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(REPO / "launch" / "replay_scan.yaml"),
               "--run-dir", str(out / "run"), "--no-progress", f"bag:={args.run_dir / 'recording.mcap'}",
               f"geometry:={geo}", "thickness:=geometry", "rate:=4.0"]
        if cal.exists():
            cmd.append(f"calibration:={cal}")
        subprocess.run(cmd, check=True, cwd=REPO, stdout=subprocess.DEVNULL)
        mdir = out / "run" / "map"
        found = json.loads((mdir / "inclusions.json").read_text())
        with np.load(mdir / "map.npz") as z:
            grid = {k: z[k] for k in ("stiffness", "x_mm", "y_mm", "count")}
        s = score_scan(ph, found, grid)
        base = background(grid["stiffness"])[0]
        rows.append({"bias_mm": bias, "baseline_kpa": base, "found": s.found, "false_positives": len(s.false_positives),
                     "sensitivity": s.sensitivity, "specificity": s.specificity,
                     "centroid_errors_mm": [i.centroid_error_mm for i in s.inclusions],
                     "contrasts": [i.detection.contrast if i.detection else None for i in s.inclusions]})
        r = rows[-1]
        print(f"bias {bias:+.1f} mm: baseline {base:5.1f} kPa, found {s.found}/4, FP {r['false_positives']}, "
              f"sens {s.sensitivity:.2f} spec {s.specificity:.3f}, errors "
              + ", ".join("miss" if np.isnan(e) else f"{e:.1f}" for e in r["centroid_errors_mm"]), flush=True)
    print(f"wall {time.perf_counter() - t0:.0f} s")
    print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
