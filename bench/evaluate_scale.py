"""What a sweep of tools.evaluate costs on this machine, and on paper on N workers (issue 40).

    .venv/bin/python bench/evaluate_scale.py                # 4 small rasters on 1 worker, then on 2
    .venv/bin/python bench/evaluate_scale.py --runs 8 --launch-cpu-s 40

The same sweep (``--runs`` small rasters: generated phantoms, a 16 x 16 mm region, 4 mm lines) runs on a local
Dask cluster of 1 worker, then of 2, each into a fresh folder, through ``tools.evaluate.main`` (the real runner).
For each: wall time, CPU time (this process and every process it started: the workers and their launches, user +
system; and the launches' own, the runs table's ``cpu_s``) and the load average. From those: **runs per CPU-hour** (CPU time is what a busy shared machine moves
least), the **speed-up of 2 workers over 1** (wall over wall: on two cores shared with others it is what is
left of the second core) and whether both gave the same tables (wall-clock columns aside).

**On paper**, a 1 000-phantom x 3-draw comparison (bench/adaptive.py: raster and adaptive per phantom and draw,
6 000 launches) on N workers: CPU-hours = launches x ``--launch-cpu-s`` / 3600; wall hours on N workers with a
core each = CPU-hours / N plus one run's length (the runs are independent: Dask adds a task's round trip, ms), and
the same at the efficiency measured here (speed-up / 2: on a shared machine, what the second worker got). ``--launch-cpu-s`` is one
full-size launch's CPU seconds (default: the measured mean of a shipped-phantom raster + adaptive pair,
BENCHMARKS.md "Sweeps"). The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from tools.evaluate import main as evaluate  # noqa: E402
from tools.evaluate_tables import TABLES, WALL_CLOCK, read_tables  # noqa: E402

LAUNCH_CPU_S = 9.4
"""One full-size launch's CPU seconds: the mean of the shipped phantom's raster and adaptive runs (BENCHMARKS.md)."""


def _cpu_s() -> float:
    """User + system CPU seconds of this process and of every child it has waited for (the cluster's workers
    are waited for when it closes, and they for their launches)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def sweep(out: Path, runs: int, workers: int) -> dict[str, Any]:
    """The bench sweep on ``workers`` local workers into ``out``: wall, CPU, load."""
    argv = [str(REPO / "launch" / "scan_sim.yaml"), "--generate", str(runs), "--phantom-seed", "3", "-o", str(out),
            "--workers", str(workers), "--arg", "region_mm=[[6.0, 6.0, 22.0, 22.0]]", "--arg", "spacing_mm=4.0",
            "--arg", "touch_grid=2"]
    load0, cpu0, t0 = os.getloadavg()[0], _cpu_s(), time.monotonic()
    code = evaluate(argv)
    wall, cpu = time.monotonic() - t0, _cpu_s() - cpu0
    if code != 0:
        raise SystemExit(f"the sweep on {workers} worker(s) failed (exit {code}): see {out}/runs.csv")
    launches_cpu = float(read_tables(out)[0]["runs"]["cpu_s"].sum())
    return {"workers": workers, "runs": runs, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
            "launches_cpu_s": round(launches_cpu, 1), "load_before": round(load0, 2),
            "load_after": round(os.getloadavg()[0], 2), "runs_per_cpu_hour": round(runs / cpu * 3600, 1)}


def _same_tables(a: Path, b: Path) -> bool:
    ta, _ = read_tables(a)
    tb, _ = read_tables(b)
    return all(ta[n].drop(columns=[c for c in WALL_CLOCK if c in ta[n]]).equals(
        tb[n].drop(columns=[c for c in WALL_CLOCK if c in tb[n]])) for n in TABLES)


def on_paper(launch_cpu_s: float, efficiency: float, workers: tuple[int, ...] = (2, 8, 32, 128)) -> dict[str, Any]:
    """A 1 000-phantom x 3-draw comparison (two methods: 6 000 launches): CPU-hours, and wall hours on each N with
    a core each (and at ``efficiency``)."""
    launches = 1000 * 3 * 2
    cpu_h = launches * launch_cpu_s / 3600
    return {"launches": launches, "cpu_hours": round(cpu_h, 1),
            "wall_hours": {n: round(cpu_h / n + launch_cpu_s / 3600, 2) for n in workers},
            "wall_hours_at_efficiency": {n: round(cpu_h / (n * efficiency) + launch_cpu_s / 3600, 2)
                                         for n in workers}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=4, help="runs in the sweep (small rasters)")
    ap.add_argument("--launch-cpu-s", type=float, default=LAUNCH_CPU_S,
                    help="one full-size launch's CPU seconds, for the paper estimate")
    ap.add_argument("--keep", type=Path, help="keep the sweeps' folders here (default: a temporary folder)")
    opts = ap.parse_args(argv)
    if opts.runs < 2:
        ap.error("--runs: at least 2 (two workers need two runs)")
    with tempfile.TemporaryDirectory(prefix="eval-scale-") as tmp:
        root = opts.keep or Path(tmp)
        one = sweep(root / "w1", opts.runs, 1)
        two = sweep(root / "w2", opts.runs, 2)
        same = _same_tables(root / "w1", root / "w2")
    speedup = one["wall_s"] / two["wall_s"]
    efficiency = min(1.0, speedup / 2)
    paper = on_paper(opts.launch_cpu_s, efficiency)
    for m in (one, two):
        print(f"{m['workers']} worker(s): {m['runs']} runs in {m['wall_s']} s wall, {m['cpu_s']} CPU-s "
              f"({m['runs_per_cpu_hour']} runs per CPU-hour; the launches themselves {m['launches_cpu_s']} CPU-s, "
              f"the rest is Dask and the runner), load {m['load_before']} -> {m['load_after']}")
    print(f"speed-up of 2 workers over 1: {speedup:.2f}x; same tables: {same}")
    print(f"on paper, 1000 phantoms x 3 draws x 2 methods = {paper['launches']} launches at {opts.launch_cpu_s:g} "
          f"CPU-s each: {paper['cpu_hours']} CPU-hours; wall on N workers with a core each: "
          + ", ".join(f"{n}: {h} h" for n, h in paper["wall_hours"].items())
          + f"; at this machine's 2-worker efficiency ({efficiency:.2f}): "
          + ", ".join(f"{n}: {h} h" for n, h in paper["wall_hours_at_efficiency"].items()))
    print(json.dumps({"one_worker": one, "two_workers": two, "speedup_2_over_1": round(speedup, 2),
                      "same_tables": same, "on_paper": paper, "cpus": os.cpu_count()}))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
