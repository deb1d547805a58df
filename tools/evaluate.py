"""Batch evaluation: a launch file over phantoms x seeds x arg values, every run scored against its phantom's truth.

    python -m tools.evaluate launch/scan_sim.yaml --generate 20 -o runs/eval
    python -m tools.evaluate launch/scan_sim.yaml --phantom phantoms/airfloat_tumours.yaml --seeds 0 1 2 \\
        --arg spacing_mm=2,3,4 -o runs/spacing

Each run is ``palpa launch FILE --in-process`` in its own run directory (``--multi-process`` for one process per
node), a task of a sweep on dask.distributed (``tools.sweep``): a local cluster of ``--workers`` processes
(default: one per core), or a running cluster with ``--scheduler tcp://HOST:8786``; the dashboard's address is
printed, and Dask's progress bar shown on a terminal. Each run has a content key (the launch file's, the
phantom's and every file override's bytes, the seed and args, the code version), its result is kept under
``OUT/results/<key>.json`` as it finishes, and running the same sweep again runs only the runs that failed or are
missing (``--rerun``: all); docs/evaluate.md has a laptop sweep, a cluster sweep and the tables. The runner gives
the launch file the phantom (``phantom:=``), a simulated thickness measurement of it (``geometry:=``, made with
the sim's measurer, ``models.geometry.measure_phantom``), the seed (``seed:=``), and, unless set with ``--arg``,
a raster region inside the phantom (``region_mm:=``, ``--margin`` from its true edges; without ``--margin`` the
launch file's own region) and a probe height above its top (``contact_z_mm:=``, 1 mm above the thickest point):
each only if the launch file declares that arg (``tools.evaluate_plan`` makes the runs).

``--generate N`` makes N random phantoms (``models.phantom_gen``, seeds ``--phantom-seed``..+N-1) into
``OUT/phantoms`` (with ``--blank``, the same specimens without their inclusions: any detection is a false alarm).
After the runs, each one's ``inclusions.json`` and ``map.npz`` are scored with ``models.scoring.score_scan``, and
its recording gives the scan time, the path length and the number of probe samples. Written to OUT: the tables ``runs``, ``inclusions`` and ``detections`` as Parquet and CSV, ``runs.json``
(``tools.evaluate_tables``) and ``summary.txt`` (per arg combination; also printed; ``--summary OUT`` prints it
again from the Parquet tables). The truth is read here, after the runs, never by the graph's estimators.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import yaml

from messages import RobotPose, ScanStatus, StiffnessSample
from models.phantom import Phantom, load_phantom
from models.phantom_gen import PhantomRanges, random_phantom
from models.scoring import Detection, score_scan
from tools.evaluate_plan import RunSpec, plan_runs  # re-exported: they were defined here
from tools.evaluate_tables import read_tables, summarize, write_tables
from tools.sweep import Cluster, Store, Task, content_key, file_digest, run_sweep, tree_digest
from yamlstruct import Source, YamlError

__all__ = ["RunJob", "RunSpec", "main", "plan_runs", "run_and_score", "run_tasks", "scan_facts", "score_run",
           "summarize"]

REPO = Path(__file__).resolve().parent.parent
CODE = ("palpa", "nodes", "tools", "models", "messages", "devices", "yamlstruct", "launch")
"""What the code version of a run's key covers (``tools.sweep.tree_digest``)."""


def generate_phantoms(folder: Path, first_seed: int, n: int, *, blank: bool = False) -> list[Path]:
    """Write ``n`` random phantom files (models.phantom_gen, seeds ``first_seed``..+n-1) into ``folder``:
    ``random_SEED.yaml``, or with ``blank`` ``blank_SEED.yaml``: random_SEED's specimen (its size, thickness profile
    and moduli: the generator draws the inclusions last) without its inclusions. Returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    ranges = PhantomRanges(inclusions=(0, 0)) if blank else PhantomRanges()
    paths = []
    for seed in range(first_seed, first_seed + n):
        name = f"{'blank' if blank else 'random'}_{seed}"
        data = random_phantom(seed, ranges, name=name)
        if blank:
            data["description"] = f"generated blank phantom, seed {seed} (models.phantom_gen, no inclusions)"
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        paths.append(path)
    return paths


def scan_facts(recording: Path) -> dict[str, float]:
    """From a run's recording: simulated span (first to last message), simulated time to the scan's end (first
    message to the 'done' status: what a simulation had to compute, whatever ran on after it), scan time (first
    'scanning' or 'probing' to 'done' status), path length of the TCP while scanning (mm) and the number of valid probe
    (stiffness) samples."""
    from palpa.record.reader import iter_bag, resolve_bag_paths

    first = last = None
    scan_start = scan_end = None
    path = 0.0
    prev: tuple[float, float, float] | None = None
    probes = 0
    poses: list[tuple[int, tuple[float, float, float]]] = []
    for m in iter_bag(resolve_bag_paths(str(recording))):
        t = m.publish_time
        first = t if first is None else min(first, t)
        last = t if last is None else max(last, t)
        if m.topic == "robot/scan_status":
            st = msgspec.msgpack.decode(m.payload, type=ScanStatus)
            # the scan starts with its first measuring motion: a raster's lines, an adaptive planner's first probe
            # (both after the touch-off), so that path and time compare like with like
            if st.state in ("scanning", "probing") and scan_start is None:
                scan_start = st.stamp_ns
            elif st.state == "done" and scan_end is None:
                scan_end = st.stamp_ns
        elif m.topic == "robot/pose":
            p = msgspec.msgpack.decode(m.payload, type=RobotPose)
            poses.append((p.stamp_ns, (p.x_mm, p.y_mm, p.z_mm)))
        elif m.topic == "stiffness/sample":
            probes += msgspec.msgpack.decode(m.payload, type=StiffnessSample).valid
    lo = scan_start if scan_start is not None else -1
    hi = scan_end if scan_end is not None else 1 << 63
    for stamp, xyz in sorted(poses):
        if lo <= stamp <= hi:
            if prev is not None:
                path += math.dist(prev, xyz)
            prev = xyz
    return {
        "sim_s": (last - first) / 1e9 if first is not None and last is not None else math.nan,
        "scan_s": (scan_end - scan_start) / 1e9 if scan_start is not None and scan_end is not None else math.nan,
        "to_done_s": (scan_end - first) / 1e9 if first is not None and scan_end is not None else math.nan,
        "path_mm": path,
        "probes": probes,
    }


def score_run(spec: RunSpec, phantom: Phantom) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """One row for the run and one per true inclusion (raises OSError/ValueError when outputs are missing)."""
    row, incs, _ = score_outputs(spec, phantom)
    return row, incs


def score_outputs(spec: RunSpec, phantom: Phantom, redetect: bool = False
                  ) -> tuple[dict[str, Any], list[dict[str, Any]], list[dict[str, Any]]]:
    """:func:`score_run`'s row and inclusions, and one row per detection (``inclusion``: the true one it matched,
    -1 for a false positive). ``redetect``: the detection run on ``map.npz`` again, by the rule that made the map
    (nodes.scanner.planner_map.redetect_map: a raster's map by the map detector with its probe's false-alarm law, an
    adaptive planner's by the planner's own rule), instead of the run's ``inclusions.json``; a planner's map that
    lacks what its rule needs raises ValueError (planner_map.PlannerMapError) naming the file and what is missing."""
    out = spec.run_dir / "map"
    detections = json.loads((out / "inclusions.json").read_text())
    if redetect:
        from models.stiffness_map import to_inclusions_json
        from nodes.scanner.planner_map import redetect_map

        detections = to_inclusions_json(redetect_map(out / "map.npz")[0].inclusions)
    with np.load(out / "map.npz") as grid:
        score = score_scan(phantom, detections, dict(grid))
    errors = [s.centroid_error_mm for s in score.inclusions if s.found]
    row: dict[str, Any] = {
        "true_inclusions": len(score.inclusions), "found": score.found,
        "missed": len(score.inclusions) - score.found, "false_positives": len(score.false_positives),
        "mean_centroid_error_mm": float(np.mean(errors)) if errors else math.nan,
        "max_centroid_error_mm": max(errors) if errors else math.nan,
        "sensitivity": score.sensitivity, "specificity": score.specificity, "iou": score.iou,
    }
    row.update(scan_facts(spec.run_dir / "recording.mcap"))
    incs = [{"run": spec.id, "inclusion": s.index, "radius_mm": s.radius_mm, "ratio": s.ratio,
             "depth_mm": phantom.inclusions[s.index].depth_mm, "found": s.found,
             "centroid_error_mm": s.centroid_error_mm, "radius_error_mm": s.radius_error_mm}
            for s in score.inclusions]
    matched = [(s.detection, s.index) for s in score.inclusions if s.detection is not None]
    dets = []
    for i, rec in enumerate(detections):
        d = Detection.from_record(rec, f"{out / 'inclusions.json'}[{i}]")
        hit = next((m for m in matched if m[0] == d), None)
        if hit is not None:
            matched.remove(hit)
        dets.append({"run": spec.id, "detection": i, "x_mm": d.x_mm, "y_mm": d.y_mm, "radius_mm": d.radius_mm,
                     "contrast": d.contrast, "inclusion": -1 if hit is None else hit[1]})
    return row, incs, dets


def launch_one(launch: Path, spec: RunSpec, *, in_process: bool, timeout_s: float) -> dict[str, Any]:
    """Run one launch; its exit code, wall time and CPU time (user + system of the launch and every process it
    waited for; run one launch at a time per process for that to be the launch's own) (output in its run
    directory's logs)."""
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(launch), "--run-dir", str(spec.run_dir),
           "--no-progress", *(["--in-process"] if in_process else []),
           *(f"{k}:={json.dumps(v)}" for k, v in spec.overrides.items())]
    t0, cpu0 = time.monotonic(), _children_cpu_s()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, preexec_fn=_end_with_parent)
        code, tail = proc.returncode, proc.stderr[-2000:]
    except subprocess.TimeoutExpired:
        code, tail = -1, f"timed out after {timeout_s:g} s"
    return {"exit_code": code, "wall_s": time.monotonic() - t0, "cpu_s": _children_cpu_s() - cpu0, "tail": tail}


def _children_cpu_s() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def _end_with_parent() -> None:
    """In the launch's child, before exec (Linux): SIGTERM it when the process that started it dies, so a sweep
    worker killed mid-run leaves no launch behind writing into the run directory its retry starts afresh."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def _parse_grid(items: Sequence[str]) -> dict[str, list[Any]]:
    grid: dict[str, list[Any]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not name or not values:
            raise SystemExit(f"--arg {item!r}: expected NAME=V1,V2,... (values are YAML; a list in brackets)")
        text = values if values.startswith("[[") else f"[{values}]"
        try:
            parsed = Source.from_text(text, f"--arg {name}").data
        except YamlError as exc:
            raise SystemExit(f"--arg {item!r}: {exc}") from None
        grid[name] = list(parsed)
    return grid


@dataclass(frozen=True)
class RunJob:
    """One task of a sweep: launch ``spec`` with ``launch`` (absolute paths: a worker runs elsewhere) and score it."""

    launch: Path
    spec: RunSpec
    in_process: bool = True
    timeout_s: float = 900.0


def run_key(job: RunJob, code: str) -> str:
    """The run's content key: the launch file's bytes, the run id, seed and overrides (an override naming a file:
    that file's bytes), the process mode and ``code`` (the code version)."""
    def content(v: Any) -> Any:
        return {"file": file_digest(Path(v))} if isinstance(v, str) and Path(v).is_file() else v

    return content_key({"launch": file_digest(job.launch), "run": job.spec.id, "seed": job.spec.seed,
                        "overrides": {k: content(v) for k, v in job.spec.overrides.items()},
                        "in_process": job.in_process, "code": code})


def run_and_score(job: RunJob) -> dict[str, Any]:
    """A sweep task (on a worker): launch the run in a fresh run directory and score it. ``row`` (exit code,
    wall time and the scores), ``inclusions``, ``detections`` and ``error`` ("" when scored)."""
    spec = job.spec
    shutil.rmtree(spec.run_dir, ignore_errors=True)  # a retried run starts from nothing
    ran = launch_one(job.launch, spec, in_process=job.in_process, timeout_s=job.timeout_s)
    row: dict[str, Any] = {"exit_code": ran["exit_code"], "wall_s": round(ran["wall_s"], 2),
                           "cpu_s": round(ran["cpu_s"], 2)}
    if ran["exit_code"] != 0:
        return {"row": row, "error": f"launch failed ({ran['exit_code']}): {ran['tail'].strip().splitlines()[-1:]}"}
    try:
        scored, incs, dets = score_outputs(spec, load_phantom(spec.phantom))
    except (OSError, ValueError, KeyError) as exc:
        return {"row": row, "error": f"cannot score: {exc}"}
    return {"row": {**row, **scored}, "inclusions": incs, "detections": dets, "error": ""}


def redetected(spec: RunSpec) -> dict[str, Any]:
    """A record as :func:`run_tasks` gives one, for a run an earlier sweep left in its run directory, scored with
    the detection run on its ``map.npz`` again by the rule that made it (``--redetect``: nothing is launched;
    :func:`score_outputs`); a map that cannot be detected on again is the run's error."""
    from nodes.mapping.map_output import map_incomplete

    try:
        why = map_incomplete(spec.run_dir / "map" / "map.npz")
        scored, incs, dets = score_outputs(spec, load_phantom(spec.phantom), redetect=True)
    except (OSError, ValueError, KeyError) as exc:
        return {"key": "", "ok": False, "error": f"cannot score: {exc}", "result": {}}
    if why:  # the run's own map said it is partial: its launch failed then, and a new detection does not mend it
        return {"key": "", "ok": False, "error": f"the map is INCOMPLETE: {why}", "result": {}}
    return {"key": "", "ok": True, "error": "", "result": {"row": scored, "inclusions": incs, "detections": dets}}


def run_tasks(jobs: Sequence[RunJob], out: Path, where: Cluster, *, rerun: bool = False,
              progress: bool | None = None) -> list[dict[str, Any]]:
    """Run ``jobs`` as one sweep (``tools.sweep``), their results kept under ``OUT/results``: every job's record
    (``ok``, ``error``, ``result`` = :func:`run_and_score`'s), in the order of ``jobs``."""
    code = tree_digest(REPO, CODE)
    tasks = [Task(run_key(j, code), j.spec.id, run_and_score, j) for j in jobs]
    return run_sweep(tasks, Store(out / "results"), where, rerun=rerun, progress=progress)


def tables_of(specs: Sequence[RunSpec], records: Sequence[dict[str, Any]],
              shown: dict[str, str]) -> dict[str, list[dict[str, Any]]]:
    """The runs, inclusions and detections rows of a sweep's records (``shown``: each run's phantom as given)."""
    tables: dict[str, list[dict[str, Any]]] = {"runs": [], "inclusions": [], "detections": []}
    for spec, rec in zip(specs, records, strict=True):
        result = rec["result"]  # a task Dask gave up on has only its error
        tables["runs"].append({"run": spec.id, "key": rec["key"], "phantom": shown[spec.id], "seed": spec.seed,
                               **spec.args, **result.get("row", {}), "error": rec["error"]})
        tables["inclusions"] += result.get("inclusions", [])
        tables["detections"] += result.get("detections", [])
    return tables


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.evaluate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("launch", type=Path, nargs="?", help="the launch file to evaluate")
    ap.add_argument("-o", "--out", type=Path, help="output folder (runs, results, tables, summary)")
    ap.add_argument("--summary", type=Path, metavar="DIR", help="print the summary of the sweep in DIR (its "
                    "Parquet tables) and run nothing")
    ap.add_argument("--phantom", action="append", type=Path, default=[], help="a phantom file (repeatable)")
    ap.add_argument("--generate", type=int, default=0, metavar="N", help="also N random phantoms")
    ap.add_argument("--phantom-seed", type=int, default=0, help="seed of the first generated phantom")
    ap.add_argument("--blank", action="store_true", help="the generated phantoms without inclusions (blank_SEED: "
                    "every detection on them is false, a check of the stated false-alarm rate on varied specimens)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="run seeds (sensor noise, measurement)")
    ap.add_argument("--arg", action="append", default=[], metavar="NAME=V1,V2",
                    help="vary a launch arg over these values (repeatable: the runs take every combination)")
    add_cluster_args(ap)
    ap.add_argument("--rerun", action="store_true", help="run every run again, even those with a result")
    ap.add_argument("--redetect", action="store_true", help="launch nothing: score the runs already in OUT with the "
                    "detection run on each map.npz again by the rule that made it (a raster's map: models.detector; "
                    "an adaptive planner's: its own; the detector is cheap, scans are not)")
    ap.add_argument("--multi-process", action="store_true", help="one process per node instead of --in-process")
    ap.add_argument("--margin", type=float, default=None,
                    help="raster margin inside the phantom's true edges (mm); default: the launch file's own region "
                         "(scan_sim.yaml: the measured footprint less its edge margin, which keeps the SPS ring on "
                         "the specimen)")
    ap.add_argument("--geometry-error", type=float, default=0.2, help="simulated thickness measurement σ (mm)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds before a run is killed")
    opts = ap.parse_args(argv)
    if opts.summary:
        try:
            tables, varied = read_tables(opts.summary)
        except (OSError, ValueError) as exc:
            print(f"--summary: {exc}", file=sys.stderr)
            return 1
        print("\n".join(summarize(tables["runs"].to_dict("records"), varied)))
        return 0
    if opts.launch is None or opts.out is None:
        ap.error("give a launch file and -o OUT (or --summary DIR)")
    if opts.blank and not opts.generate:
        ap.error("--blank makes the generated phantoms blank: give --generate N")
    out: Path = opts.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    # every phantom by its absolute path (a worker's working directory is its own), shown in the tables as given
    # (a generated one: relative to OUT, so two output folders of the same sweep give the same tables)
    phantoms = {p.resolve(): str(p) for p in opts.phantom}
    if opts.generate:
        for path in generate_phantoms(out / "phantoms", opts.phantom_seed, opts.generate, blank=opts.blank):
            phantoms[path] = str(path.relative_to(out))
    if not phantoms:
        ap.error("give --phantom FILE and/or --generate N")
    grid = _parse_grid(opts.arg)
    launch = opts.launch.resolve()
    specs = plan_runs(launch, list(phantoms), opts.seeds, grid, out, margin_mm=opts.margin,
                      geometry_error_mm=opts.geometry_error)
    if opts.redetect:
        records = [redetected(s) for s in specs]
    else:
        jobs = [RunJob(launch, s, not opts.multi_process, opts.timeout) for s in specs]
        records = run_tasks(jobs, out, cluster_of(opts), rerun=opts.rerun)
    tables = tables_of(specs, records, {s.id: phantoms[s.phantom] for s in specs})
    write_tables(out, tables, list(grid))
    summary = summarize(tables["runs"], list(grid))
    (out / "summary.txt").write_text("\n".join(summary) + "\n", encoding="utf-8")
    print("\n".join(summary))
    print(f"tables: {out}/{{runs,inclusions,detections}}.{{parquet,csv}}, {out / 'runs.json'}; runs in {out / 'runs'}")
    return 1 if any(not r["ok"] for r in records) else 0


def add_cluster_args(ap: argparse.ArgumentParser) -> None:
    """Where a sweep runs: ``--workers``/``--jobs``, ``--scheduler``, ``--serial`` (``tools.sweep.Cluster``)."""
    ap.add_argument("--workers", "--jobs", dest="workers", type=int, default=None,
                    help="local cluster: worker processes (default: one per core)")
    ap.add_argument("--scheduler", metavar="tcp://HOST:8786", help="run on this running Dask cluster instead")
    ap.add_argument("--serial", action="store_true", help="run one by one in this process (no Dask)")


def cluster_of(opts: argparse.Namespace) -> Cluster:
    """The :class:`Cluster` that :func:`add_cluster_args`' options name (a bad count: SystemExit)."""
    if opts.workers is not None and opts.workers < 1:
        raise SystemExit(f"--workers: at least 1, got {opts.workers}")
    return Cluster(scheduler=opts.scheduler, workers=opts.workers, serial=opts.serial)


if __name__ == "__main__":
    sys.exit(main())
