"""The thickness the probe measures against the phantom's truth (issue 37): its stated error.

For each run directory (a scan with the estimator's ``thickness: probe``), reads every valid ``stiffness/sample`` of
its recording (the thickness eq. 7 used, ``thickness_mm``, at the sample's x, y) and compares it with the phantom's
true thickness there (the truth is read here, after the run, never by the graph). Prints per run and over all: the
bias (median error), the robust scatter (1.4826 MAD) and the 95th percentile of the absolute error, in mm.

    .venv/bin/python bench/probe_thickness.py runs/demo-1 runs/demo-2 --phantom phantoms/airfloat_tumours.yaml
    .venv/bin/python bench/probe_thickness.py runs/eval/runs/*      # each run's phantom from its launch file
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import msgspec
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from messages import StiffnessSample  # noqa: E402
from models.phantom import load_phantom  # noqa: E402
from palpa.record.reader import iter_bag, resolve_bag_paths  # noqa: E402
from yamlstruct import Source  # noqa: E402


def errors(run: Path, phantom: Path | None) -> np.ndarray:
    """Probe thickness less true thickness (mm) of every valid sample of the run that states one."""
    if phantom is None:   # the phantom the launch was given
        path = run / "launch.resolved.yaml"
        resolved = Source.from_text(path.read_text(), str(path)).data
        phantom = Path(next(a["default"] for a in resolved["args"] if a["name"] == "phantom"))
    ph = load_phantom(phantom)
    xs, ys, ts = [], [], []
    for m in iter_bag(resolve_bag_paths(str(run / "recording.mcap"))):
        if m.topic != "stiffness/sample":
            continue
        s = msgspec.msgpack.decode(m.payload, type=StiffnessSample)
        if s.valid and s.thickness_mm > 0:
            xs.append(s.x_mm)
            ys.append(s.y_mm)
            ts.append(s.thickness_mm)
    if not ts:
        raise SystemExit(f"{run}: no sample states its thickness (was the estimator's thickness: probe?)")
    truth = np.asarray(ph.thickness(np.array(xs), np.array(ys)), dtype=float)
    return np.array(ts) - truth


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--phantom", type=Path, help="default: each run's own (its launch.resolved.yaml)")
    args = ap.parse_args()
    everything = []
    for run in args.runs:
        e = errors(run, args.phantom)
        everything.append(e)
        print(f"{run}: {e.size} samples, bias {np.median(e):+.4f} mm, scatter "
              f"{1.4826 * np.median(np.abs(e - np.median(e))):.4f} mm, |error| p95 {np.percentile(np.abs(e), 95):.4f} mm")
    e = np.concatenate(everything)
    summary = {"runs": len(args.runs), "samples": int(e.size), "bias_mm": float(np.median(e)),
               "scatter_mm": float(1.4826 * np.median(np.abs(e - np.median(e)))),
               "abs_p95_mm": float(np.percentile(np.abs(e), 95)), "abs_max_mm": float(np.max(np.abs(e)))}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
