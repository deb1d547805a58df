"""Issue 15's acceptance study: scan specimens unlike the shipped phantoms from ``phantom:=X`` alone.

For every phantom and scan launch file it runs ``palpa launch FILE phantom:=X`` (nothing else: the region, the
surface and the heights come from what the graph measures) in its own run directory, then scores the map against
the phantom's truth with ``models.scoring`` (outside the graph) and prints one line per run: the true inclusions
found, each centroid error, false positives, the touch-off's fit line and the wall time. A phantom that does not
fit the workspace must be refused (exit 1) with the box and the extent in the message, before any motion.

    python bench/specimens.py                       # every phantom in phantoms/specimens/, both launch files
    python bench/specimens.py --only dome_6_3 --launch scan_sim.yaml
    python bench/specimens.py -j 2                  # two runs at once (each is ~6 processes)
    python bench/specimens.py --only dome_6_3 --arg touch_grid:=2 --arg follow_gain_per_s:=0   # any launch arg

A scan takes minutes of wall time on a loaded 2-core machine: this is a study, not a test.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.phantom import load_phantom  # noqa: E402
from models.scoring import score_scan  # noqa: E402

LAUNCHES = ("scan_sim.yaml", "scan_camera_sim.yaml")


def run_one(launch: str, phantom: Path, out: Path, extra: list[str]) -> str:
    """Launch, score, and return one report line."""
    run = out / f"{phantom.stem}-{launch.removesuffix('.yaml')}"
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(REPO / "launch" / launch), f"phantom:={phantom}",
           *extra, "--run-dir", str(run), "--no-progress"]
    t0 = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=3600, check=False)
    wall = time.monotonic() - t0
    text = done.stdout + done.stderr
    head = f"{phantom.stem:22s} {launch:22s} exit {done.returncode}  {wall:5.0f} s"
    touch = re.search(r"((?:search: .*; )?touch-off: .*)", text)
    follow = re.search(r"surface following: (.*)", text)
    refusal = re.search(r"refusing the specimen before any motion: (.*)", text)
    if refusal:
        return f"{head}  REFUSED: {refusal.group(1)[:220]}"
    inc_file = run / "map" / "inclusions.json"
    if not inc_file.exists():
        return f"{head}  no map ({run})"
    found = json.loads(inc_file.read_text())
    with np.load(run / "map" / "map.npz") as grid:
        score = score_scan(load_phantom(phantom), found, grid)
    errs = ", ".join(f"#{s.index} r{s.radius_mm:g} x{s.ratio:.0f}: "
                     + (f"{s.centroid_error_mm:.2f} mm" if s.found else "missed") for s in score.inclusions)
    return (f"{head}  found {score.found}/{len(score.inclusions)} [{errs or 'none to find'}]  "
            f"false positives {len(score.false_positives)}  ({touch.group(1) if touch else 'no touch-off line'})"
            + (f"  (following: {follow.group(1)})" if follow else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phantoms", type=Path, default=REPO / "phantoms" / "specimens")
    ap.add_argument("--only", nargs="*", default=[], help="phantom stems to run")
    ap.add_argument("--launch", nargs="*", default=list(LAUNCHES))
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "specimens")
    ap.add_argument("-j", "--jobs", type=int, default=1)
    ap.add_argument("--arg", action="append", default=[], help="a launch arg for every run (name:=value)")
    args = ap.parse_args()
    phantoms = sorted(p for p in args.phantoms.glob("*.yaml") if not args.only or p.stem in args.only)
    jobs = [(lf, ph) for ph in phantoms for lf in args.launch]
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        for line in pool.map(lambda j: run_one(j[0], j[1], args.out, args.arg), jobs):
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
