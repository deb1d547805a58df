"""Batch evaluation: a launch file over phantoms x seeds x arg values, every run scored against its phantom's truth.

    python -m nodes.evaluate launch/scan_sim.yaml --generate 20 -o runs/eval
    python -m nodes.evaluate launch/scan_sim.yaml --phantom phantoms/airfloat_tumours.yaml --seeds 0 1 2 \\
        --arg spacing_mm=2,3,4 -o runs/spacing

Each run is ``palpa launch FILE --in-process`` in its own run directory (``--multi-process`` for one process per
node), ``--jobs`` at a time (default: one per core), with a progress bar. The runner gives the launch file the
phantom (``phantom:=``), a simulated thickness measurement of it (``geometry:=``, made with the sim's measurer,
``models.geometry.measure_phantom``), the seed (``seed:=``), and, unless set with ``--arg``, a raster region
inside the phantom (``region_mm:=``, ``--margin`` from its true edges; without ``--margin`` the launch file's own
region) and a probe height above its top
(``contact_z_mm:=``, 1 mm above the thickest point): each only if the launch file declares that arg.

``--generate N`` makes N random phantoms (``models.phantom_gen``, seeds ``--phantom-seed``..+N-1) into
``OUT/phantoms``. After the runs, each one's ``inclusions.json`` and ``map.npz`` are scored with
``models.scoring.score_scan``, and its recording gives the scan time, the path length and the number of probe
samples. Written to OUT: ``runs.csv``/``runs.json`` (one row per run), ``inclusions.csv`` (one row per true
inclusion per run) and ``summary.txt`` (per arg combination; also printed). The truth is read here, after the
runs, never by the graph's estimators.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import yaml

from messages import RobotPose, ScanStatus, StiffnessSample
from models.geometry import measure_phantom
from models.phantom import Phantom, load_phantom
from models.phantom_gen import PhantomRanges, random_phantom
from models.scoring import score_scan
from yamlstruct import Source, YamlError

__all__ = ["RunSpec", "main", "scan_facts", "score_run"]


@dataclass
class RunSpec:
    """One launch of the batch: which phantom, seed and arg values, and where it runs."""

    id: str
    phantom: Path
    seed: int
    args: dict[str, Any]
    """The varied ``--arg`` values of this run (the combination it belongs to)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Every ``name:=value`` given to the launch (the varied args included)."""
    run_dir: Path = Path()


def scan_facts(recording: Path) -> dict[str, float]:
    """From a run's recording: simulated span (first to last message), simulated time to the scan's end (first
    message to the 'done' status: what a simulation had to compute, whatever ran on after it), scan time (first
    'scanning' to 'done' status), path length of the TCP while scanning (mm) and the number of valid probe
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
            if st.state == "scanning" and scan_start is None:
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


def score_run(spec: RunSpec, phantom: Phantom, redetect: bool = False) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """One row for the run and one per true inclusion (raises OSError/ValueError when outputs are missing);
    ``redetect``: the map detector (models.detector, the map aggregator's) run on ``map.npz`` again instead of the
    run's ``inclusions.json``."""
    out = spec.run_dir / "map"
    detections = json.loads((out / "inclusions.json").read_text())
    if redetect:
        from models.detector import detect
        from models.stiffness_map import to_inclusions_json
        from nodes.map_output import read_map

        detections = to_inclusions_json(detect(read_map(out / "map.npz")).inclusions)
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
    return row, incs


def _declared_args(launch: Path) -> set[str]:
    from palpa.launch import load_launch

    return set(load_launch(launch, {}, run_dir=Path("runs") / "unused").args)


def plan_runs(launch: Path, phantoms: Sequence[Path], seeds: Sequence[int], grid: dict[str, list[Any]],
              out: Path, *, margin_mm: float | None, geometry_error_mm: float) -> list[RunSpec]:
    """Every phantom x seed x arg combination, with the overrides the launch file can take (module doc)."""
    declared = _declared_args(launch)
    unknown = sorted(set(grid) - declared)
    if unknown:
        raise SystemExit(f"{launch}: no arg named {', '.join(unknown)} (it declares {', '.join(sorted(declared))})")
    if "phantom" not in declared:
        raise SystemExit(f"{launch}: declares no 'phantom' arg: the runner cannot give it a world")
    combos = [dict(zip(grid, values, strict=True)) for values in itertools.product(*grid.values())] or [{}]
    (out / "geometry").mkdir(parents=True, exist_ok=True)
    specs = []
    for ph_path in phantoms:
        ph = load_phantom(ph_path)
        for seed in seeds:
            base: dict[str, Any] = {"phantom": str(ph_path.resolve())}
            if "geometry" in declared:
                geo = out / "geometry" / f"{ph_path.stem}-seed{seed}.yaml"
                measured = measure_phantom(ph, error_mm=geometry_error_mm, seed=seed)
                geo.write_text(yaml.safe_dump(measured.to_yaml_data(), sort_keys=False), encoding="utf-8")
                base["geometry"] = str(geo.resolve())
            if "seed" in declared:
                base["seed"] = seed
            if "region_mm" in declared and margin_mm is not None:
                w, h = ph.size_mm
                base["region_mm"] = [margin_mm, margin_mm, round(w - margin_mm, 3), round(h - margin_mm, 3)]
            if "contact_z_mm" in declared:
                top = float(np.nanmax(ph.thickness(np.linspace(0, ph.size_mm[0], 25)[:, None],
                                                   np.linspace(0, ph.size_mm[1], 25)[None, :])))
                base["contact_z_mm"] = round(top + 1.0, 3)
            for i, combo in enumerate(combos):
                rid = f"{ph_path.stem}-s{seed}" + (f"-a{i}" if len(combos) > 1 else "")
                specs.append(RunSpec(rid, ph_path, seed, combo, {**base, **combo}, out / "runs" / rid))
    return specs


def launch_one(launch: Path, spec: RunSpec, *, in_process: bool, timeout_s: float) -> dict[str, Any]:
    """Run one launch; its exit code and wall time (output in its run directory's logs)."""
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(launch), "--run-dir", str(spec.run_dir),
           "--no-progress", *(["--in-process"] if in_process else []),
           *(f"{k}:={json.dumps(v)}" for k, v in spec.overrides.items())]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        code, tail = proc.returncode, proc.stderr[-2000:]
    except subprocess.TimeoutExpired:
        code, tail = -1, f"timed out after {timeout_s:g} s"
    return {"exit_code": code, "wall_s": time.monotonic() - t0, "tail": tail}


def summarize(rows: list[dict[str, Any]], varied: Sequence[str]) -> list[str]:
    """Per arg combination: runs (failed), inclusions found of all, false positives, mean sensitivity,
    specificity and centroid error, mean scan time."""
    lines = []
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(json.dumps(r.get(k)) for k in varied), []).append(r)
    for key, group in groups.items():
        ok = [r for r in group if not r.get("error")]
        label = ", ".join(f"{k}={v}" for k, v in zip(varied, key, strict=True)) or "all runs"

        def mean(name: str, rs: list[dict[str, Any]] = ok) -> float:
            vals = [float(r[name]) for r in rs if isinstance(r.get(name), int | float) and math.isfinite(r[name])]
            return float(np.mean(vals)) if vals else math.nan

        found = sum(r["found"] for r in ok)
        total = sum(r["true_inclusions"] for r in ok)
        errors = [r["mean_centroid_error_mm"] for r in ok if math.isfinite(r["mean_centroid_error_mm"])]
        lines.append(
            f"{label}: {len(ok)} of {len(group)} runs scored; inclusions found {found}/{total}"
            + (f" ({100 * found / total:.0f} %)" if total else "; no inclusions in these phantoms")
            + f"; false positives {sum(r['false_positives'] for r in ok)}"
            f"; sensitivity {mean('sensitivity'):.2f}, specificity {mean('specificity'):.3f}, IoU {mean('iou'):.2f}"
            f"; centroid error {np.mean(errors) if errors else math.nan:.2f} mm"
            f"; scan {mean('scan_s'):.0f} s, path {mean('path_mm'):.0f} mm, {mean('probes'):.0f} probe samples")
    return lines


def _write_tables(out: Path, rows: list[dict[str, Any]], incs: list[dict[str, Any]]) -> None:
    (out / "runs.json").write_text(json.dumps(rows, indent=1, default=str), encoding="utf-8")
    for name, table in (("runs.csv", rows), ("inclusions.csv", incs)):
        keys: list[str] = []
        for r in table:
            keys += [k for k in r if k not in keys]
        with open(out / name, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=keys)
            w.writeheader()
            w.writerows({k: json.dumps(v) if isinstance(v, list | dict) else v for k, v in r.items()} for r in table)


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


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nodes.evaluate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("launch", type=Path, help="the launch file to evaluate")
    ap.add_argument("-o", "--out", type=Path, required=True, help="output folder (runs, tables, summary)")
    ap.add_argument("--phantom", action="append", type=Path, default=[], help="a phantom file (repeatable)")
    ap.add_argument("--generate", type=int, default=0, metavar="N", help="also N random phantoms")
    ap.add_argument("--phantom-seed", type=int, default=0, help="seed of the first generated phantom")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="run seeds (sensor noise, measurement)")
    ap.add_argument("--arg", action="append", default=[], metavar="NAME=V1,V2",
                    help="vary a launch arg over these values (repeatable: the runs take every combination)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="launches at a time (default: cores)")
    ap.add_argument("--multi-process", action="store_true", help="one process per node instead of --in-process")
    ap.add_argument("--margin", type=float, default=None,
                    help="raster margin inside the phantom's true edges (mm); default: the launch file's own region "
                         "(scan_sim.yaml: the measured footprint less its edge margin, which keeps the SPS ring on "
                         "the specimen)")
    ap.add_argument("--geometry-error", type=float, default=0.2, help="simulated thickness measurement σ (mm)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds before a run is killed")
    ap.add_argument("--rescore", action="store_true",
                    help="launch nothing: score the runs an earlier call with the same arguments left in OUT")
    ap.add_argument("--redetect", action="store_true",
                    help="score the map detector (models.detector) run on each map.npz again, not its inclusions.json")
    opts = ap.parse_args(argv)
    out: Path = opts.out
    out.mkdir(parents=True, exist_ok=True)
    phantoms = list(opts.phantom)
    if opts.generate:
        (out / "phantoms").mkdir(exist_ok=True)
        for seed in range(opts.phantom_seed, opts.phantom_seed + opts.generate):
            path = out / "phantoms" / f"random_{seed}.yaml"
            path.write_text(yaml.safe_dump(random_phantom(seed, PhantomRanges()), sort_keys=False), encoding="utf-8")
            phantoms.append(path)
    if not phantoms:
        ap.error("give --phantom FILE and/or --generate N")
    grid = _parse_grid(opts.arg)
    specs = plan_runs(opts.launch, phantoms, opts.seeds, grid, out, margin_mm=opts.margin,
                      geometry_error_mm=opts.geometry_error)
    rows, incs = _rescore(opts, specs) if opts.rescore else _run_all(opts, specs)
    _write_tables(out, rows, incs)
    summary = summarize(rows, list(grid))
    (out / "summary.txt").write_text("\n".join(summary) + "\n", encoding="utf-8")
    print("\n".join(summary))
    print(f"tables: {out / 'runs.csv'}, {out / 'inclusions.csv'}, {out / 'runs.json'}; runs in {out / 'runs'}")
    return 1 if any(r.get("error") for r in rows) else 0


def _score_row(spec: RunSpec, ran: dict[str, Any], redetect: bool) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The run's row (its launch's outcome and, when it ran clean, its score) and its per-inclusion rows."""
    row: dict[str, Any] = {"run": spec.id, "phantom": str(spec.phantom), "seed": spec.seed, **spec.args,
                           "exit_code": ran["exit_code"], "wall_s": round(ran["wall_s"], 2), "error": ""}
    incs: list[dict[str, Any]] = []
    if ran["exit_code"] != 0:
        row["error"] = f"launch failed ({ran['exit_code']}): {ran['tail'].strip().splitlines()[-1:]}"
    else:
        try:
            scored, incs = score_run(spec, load_phantom(spec.phantom), redetect)
            row.update(scored)
        except (OSError, ValueError, KeyError) as exc:
            row["error"] = f"cannot score: {exc}"
    return row, incs


def _rescore(opts: argparse.Namespace, specs: list[RunSpec]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Every run's score from what an earlier call left in its run directory (``--rescore``)."""
    rows: list[dict[str, Any]] = []
    incs: list[dict[str, Any]] = []
    for spec in specs:
        row, per_inclusion = _score_row(spec, {"exit_code": 0, "wall_s": 0.0, "tail": ""}, opts.redetect)
        if row["error"]:
            print(f"{spec.id}: {row['error']}", file=sys.stderr)
        rows.append(row)
        incs += per_inclusion
    return rows, incs


def _run_all(opts: argparse.Namespace, specs: list[RunSpec]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    rows: list[dict[str, Any]] = []
    incs: list[dict[str, Any]] = []
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  transient=False) as bar, ThreadPoolExecutor(max(1, opts.jobs)) as pool:
        task = bar.add_task(f"{opts.launch.name}: {len(specs)} runs", total=len(specs))
        futures = {pool.submit(launch_one, opts.launch, s, in_process=not opts.multi_process,
                               timeout_s=opts.timeout): s for s in specs}
        for fut in as_completed(futures):
            spec = futures[fut]
            row, per_inclusion = _score_row(spec, fut.result(), opts.redetect)
            incs += per_inclusion
            if row["error"]:
                bar.console.print(f"[red]{spec.id}: {row['error']}[/red]")
            rows.append(row)
            bar.advance(task)
    order = {s.id: i for i, s in enumerate(specs)}
    rows.sort(key=lambda r: order[r["run"]])
    return rows, incs


if __name__ == "__main__":
    sys.exit(main())
