"""CPU time of each process of one multi-process demo scan (``launch/scan_sim.yaml``): where an instant's cost goes.

    python bench/sim_cpu.py                                  # a third of the demo at time_scale 20
    python bench/sim_cpu.py --region 30,6,54,30 --repo ../main  # the same with another checkout's code (paired runs)
    python bench/sim_cpu.py --in-process --region ''          # the whole demo composed: what its one process costs

Every Python process of the launch writes its own ``getrusage(RUSAGE_SELF)`` (user + system, every thread) at
exit, through a ``sitecustomize`` put first on its ``PYTHONPATH``; the table names each process by its node (the
launcher, which runs the bus proxy, is ``proxy (launcher)``). Load is the 1-minute average before -> after. The
last line is JSON. Compare runs made back to back: the machine is shared, and CPU time stretches with the load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tools.evaluate import scan_facts

REPO = Path(__file__).resolve().parent.parent

_SITECUSTOMIZE = '''
import atexit, json, os, resource, sys

def _palpa_bench_rusage() -> None:
    r = resource.getrusage(resource.RUSAGE_SELF)
    with open(os.path.join(os.environ["PALPA_BENCH_RUSAGE_DIR"], f"{os.getpid()}.json"), "w") as f:
        json.dump({"argv": sys.argv, "cpu_s": r.ru_utime + r.ru_stime}, f)

if os.environ.get("PALPA_BENCH_RUSAGE_DIR"):
    atexit.register(_palpa_bench_rusage)
'''


def _name(argv: list[str]) -> str:
    """The node a process ran (its ``--name``/``__name:=``), or what it was."""
    for i, a in enumerate(argv):
        if a in ("--name", "-n") and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith("__name:="):
            return a.split(":=", 1)[1]
    if any(a == "launch" for a in argv):
        return "proxy (launcher)"
    script = Path(argv[0]).name if argv else ""
    for file, what in (("compose.py", "composed nodes"), ("map_output.py", "map.png helper"),
                       ("geometry.py", "prepare (measurer)")):
        if script == file:
            return what
    return " ".join(argv)[:40]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--region", default="30.0,6.0,54.0,30.0", help="x0,y0,x1,y1 of the raster ('' = the demo's)")
    ap.add_argument("--time-scale", type=float, default=20.0)
    ap.add_argument("--repo", type=Path, default=REPO, help="the checkout whose code runs (default: this one)")
    ap.add_argument("--keep", type=Path, help="keep the run directory here")
    ap.add_argument("--in-process", action="store_true", help="compose the nodes in one process (--in-process)")
    opts = ap.parse_args()
    repo = opts.repo.resolve()
    work = Path(tempfile.mkdtemp(prefix="palpa-sim-cpu-"))
    site, rusage = work / "site", work / "rusage"
    site.mkdir()
    rusage.mkdir()
    (site / "sitecustomize.py").write_text(_SITECUSTOMIZE)
    run_dir = opts.keep or work / "run"
    env = {**os.environ, "PYTHONPATH": f"{site}:{repo}", "PALPA_BENCH_RUSAGE_DIR": str(rusage)}
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(repo / "launch" / "scan_sim.yaml"),
           "--run-dir", str(run_dir), "--no-progress", f"time_scale:={opts.time_scale:g}"]
    if opts.region:
        cmd.append(f"region_mm:=[{opts.region}]")
    if opts.in_process:
        cmd.append("--in-process")
    load0 = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=900)
    wall = time.monotonic() - t0
    load1 = os.getloadavg()[0]
    if proc.returncode != 0:
        raise SystemExit(f"launch failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    cpu: dict[str, float] = {}
    for f in rusage.glob("*.json"):
        d = json.loads(f.read_text())
        name = _name(d["argv"])
        cpu[name] = cpu.get(name, 0.0) + d["cpu_s"]
    facts = scan_facts(run_dir / "recording.mcap")
    inclusions = json.loads((run_dir / "map" / "inclusions.json").read_text())
    total = sum(cpu.values())
    print(f"{repo}: load {load0:.1f} -> {load1:.1f}; wall {wall:.1f} s; {facts['to_done_s']:.1f} simulated s; "
          f"CPU {total:.1f} s")
    for name, s in sorted(cpu.items(), key=lambda kv: -kv[1]):
        print(f"  {name:24s} {s:5.1f}")
    print("inclusions:", [(round(i["x_mm"], 3), round(i["y_mm"], 3)) for i in inclusions])
    print(json.dumps({"repo": str(repo), "load": [round(load0, 1), round(load1, 1)], "wall_s": round(wall, 1),
                      "sim_s": round(facts["to_done_s"], 2), "cpu_s": round(total, 1),
                      "per_process": {k: round(v, 2) for k, v in cpu.items()}, "facts": facts,
                      "inclusions": inclusions}))


if __name__ == "__main__":
    main()
