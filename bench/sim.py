"""Simulated seconds per wall second of the demo scan (launch/scan_sim.yaml), composed in one process and as one
process per node, in the same run; and whether both find the same inclusions.

    python bench/sim.py                      # the whole demo scan (about 86 s simulated)
    python bench/sim.py --region 2,2,58,20   # a third of it
    python bench/sim.py --time-scale 20      # the multi-process clock's ceiling (default 20: not the limit)
    python bench/sim.py --lockstep lead      # the multi-process clock's lead mode (faster; runs differ)

Wall time is the whole ``palpa launch`` (start-up, imports and shutdown included), as a user waits for it; CPU
time is every process of the launch (user + system), which a busy shared machine moves much less.
Simulated time is the recording's first message to the scanner's 'done' (the same in both modes: a
multi-process graph's time runs on while the launcher stops it, and the recording's whole span would count that). The machine is shared: each run reports its load
average and the CPU time the hypervisor took (steal). The last line is JSON with ``sim_speedup_in_process`` and
``sim_speedup_multi_process``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from machine import steal_ticks

from tools.evaluate import scan_facts

REPO = Path(__file__).resolve().parent.parent


def run(mode: str, run_dir: Path, args: list[str]) -> dict[str, Any]:
    """One launch of the demo scan; its wall time, simulated time, CPU time of its processes, load and steal."""
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(REPO / "launch" / "scan_sim.yaml"),
           "--run-dir", str(run_dir), "--no-progress", *args]
    if mode == "in_process":
        cmd.append("--in-process")
    load0, steal0 = os.getloadavg()[0], steal_ticks()
    cpu0 = os.times()
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900)
    wall = time.monotonic() - t0
    cpu1 = os.times()
    if proc.returncode != 0:
        raise SystemExit(f"{mode}: launch failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    sim = scan_facts(run_dir / "recording.mcap")["to_done_s"]
    cpu = (cpu1.children_user - cpu0.children_user) + (cpu1.children_system - cpu0.children_system)
    return {"mode": mode, "sim_s": sim, "wall_s": wall, "speedup": sim / wall, "cpu_s": cpu,
            "load_before": load0, "load_after": os.getloadavg()[0],
            "steal_s": (steal_ticks() - steal0) / os.sysconf("SC_CLK_TCK"),
            "inclusions": json.loads((run_dir / "map" / "inclusions.json").read_text())}


def max_centroid_gap(a: list[dict[str, float]], b: list[dict[str, float]]) -> float:
    """Largest distance (mm) from an inclusion of one run to the nearest of the other (inf if the counts differ)."""
    if len(a) != len(b):
        return math.inf
    if not a:
        return 0.0
    gaps = [min(math.dist((x["x_mm"], x["y_mm"]), (y["x_mm"], y["y_mm"])) for y in b) for x in a]
    gaps += [min(math.dist((x["x_mm"], x["y_mm"]), (y["x_mm"], y["y_mm"])) for y in a) for x in b]
    return max(gaps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--region", help="x0,y0,x1,y1 of the raster (default: the demo's)")
    ap.add_argument("--time-scale", type=float, default=20.0, help="multi-process clock ceiling (default 20)")
    ap.add_argument("--lockstep", choices=["events", "lead"], default="events",
                    help="the multi-process clock's lockstep (scan_sim.yaml's lockstep arg; default events)")
    ap.add_argument("--keep", type=Path, help="keep the run directories here")
    opts = ap.parse_args()
    extra = [f"region_mm:=[{opts.region}]"] if opts.region else []
    base = opts.keep or Path(tempfile.mkdtemp(prefix="palpa-bench-sim-"))
    results = {}
    for mode, args in (("in_process", extra), ("multi_process", [*extra, f"time_scale:={opts.time_scale:g}",
                                                                       f"lockstep:={opts.lockstep}"])):
        r = results[mode] = run(mode, base / mode, args)
        print(f"{mode:14s} {r['sim_s']:6.1f} s simulated in {r['wall_s']:6.1f} s wall = {r['speedup']:5.2f}x "
              f"real time; {r['cpu_s']:6.1f} CPU-s; load {r['load_before']:.2f} -> {r['load_after']:.2f}; "
              f"steal {r['steal_s']:.1f} s; {len(r['inclusions'])} inclusions")
    gap = max_centroid_gap(results["in_process"]["inclusions"], results["multi_process"]["inclusions"])
    print(f"inclusions: largest centroid gap between the two runs {gap:.3f} mm")
    print(json.dumps({
        "sim_speedup_in_process": round(results["in_process"]["speedup"], 2),
        "sim_speedup_multi_process": round(results["multi_process"]["speedup"], 2),
        "cpu_s_in_process": round(results["in_process"]["cpu_s"], 1),
        "cpu_s_multi_process": round(results["multi_process"]["cpu_s"], 1),
        "sim_s_per_cpu_s_in_process": round(results["in_process"]["sim_s"] / results["in_process"]["cpu_s"], 2),
        "sim_s_per_cpu_s_multi_process": round(results["multi_process"]["sim_s"] / results["multi_process"]["cpu_s"],
                                               2),
        "load_max": round(max(max(r["load_before"], r["load_after"]) for r in results.values()), 2),
        "steal_s": round(sum(r["steal_s"] for r in results.values()), 1),
        "inclusion_gap_mm": None if math.isinf(gap) else round(gap, 3),
        "lockstep": opts.lockstep,
        "cores": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
