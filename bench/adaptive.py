"""Raster against adaptive palpation (issue 20), through the batch runner's pieces (tools.evaluate).

    .venv/bin/python bench/adaptive.py -o runs/bench_adaptive --generate 20 --workers 2

Runs ``launch/scan_sim.yaml`` (the 3 mm sweep raster) and ``launch/scan_adaptive_sim.yaml`` (the GP planner) on the
shipped phantom and N generated ones (``models.phantom_gen`` seeds 0..N-1), each ``palpa launch --in-process`` in
its own run directory, all of them one sweep of the batch runner's engine (``tools.evaluate.run_tasks``,
``tools.sweep``: a local Dask cluster, ``--workers`` processes, or ``--scheduler tcp://HOST:8786``; a run whose
result is kept under ``OUT/results`` with the same content key is not run again: ``--rerun`` to force), scores
every map with ``models.scoring`` against its phantom, and compares per phantom:

* probes: the adaptive planner's probes (``planner.json``) against the raster's *probe equivalents*, its swept
  length in contact divided by the planner's sweep length (the raster's lines over the region), so one unit is the
  same 6 mm of tissue swept in both; also path length (all motion), valid samples and simulated time;
* found / missed inclusions, centroid error, cell sensitivity, specificity and IoU against the inclusion mask.

Writes ``compare.csv`` and ``error_vs_probes.png`` (error and inclusions found against probes spent: the adaptive
planner's detection map after every probe and the raster's map as it grows, both read from their recordings and scored as
a final map is) into OUT. The last line is JSON: ``time_ratio`` (simulated scan time, from the first measuring
motion after the touch-off to the planner's stop or the raster's end, adaptive over raster, summed over every run),
``path_ratio`` (the arm's path over the same span, likewise), ``time_ratio_localise`` (the planner's time pro rata to
the probe after which its map finds what the raster's final map found, over the raster's whole scan time, over the
runs where that happens), ``probe_ratio`` (the probes the planner spent until its own stop
rule stopped it, over the raster's probe equivalents, summed over the phantoms where the adaptive map found every
inclusion the raster's found: adaptive over raster probes at equal or better detection), ``probe_ratio_all`` (the
same over every phantom, whatever was missed), ``probe_ratio_localise`` (the probes after which the recorded detection map
finds, from then on, at least as many inclusions as the raster's final map: hindsight, the planner itself does not
know that moment), ``found_adaptive``, ``found_raster`` (true inclusions found over all phantoms),
``missed_vs_raster`` (inclusions the raster found and the adaptive map did not), ``missed_unsensed`` (of those,
the ones whose centre lay where the planner's map said at its stop that an inclusion of the smallest size of
interest could hide unseen, ``map.npz``'s ``unsensed``: the rest lay where its reach model said it had sensed them;
null for maps without that grid), ``phantoms``, ``runs`` (phantoms
times noise seeds; the sums above are over runs), ``complete`` (runs where the adaptive map found every inclusion the
raster's found), ``inclusions`` (true inclusions over all runs), and with ``--determinism``
``deterministic`` (the first phantom's adaptive run made again gives the same points, inclusions and map), and
with ``--same-as DIR`` ``same_as`` (every adaptive run against the same run under DIR, another output of this
script for the same seeds: ``runs`` compared, ``same``, and the ids that ``differ``).

With ``--noise-seeds K`` every phantom runs K times per method, sensor noise seeds 0..K-1 (``seed:=``): a weak
inclusion near the detector's threshold is found by the raster itself in some noise draws and not in others, so one
draw's "missed" says little about it. The rows are then (phantom, seed) pairs (``missed_vs_raster`` compares the
two methods on the same draw), ``inclusion_rates.csv`` has each true inclusion's detections out of K for both, and
the JSON adds ``noise_seeds``, ``sure_raster`` (inclusions the raster found in every draw), ``sure_missed`` (of
those, the ones the adaptive map missed in at least one), ``rate_below_raster`` / ``rate_above_raster``
(inclusions the adaptive map found in fewer / more draws than the raster's), ``raster_redraw_missed`` /
``adaptive_redraw_missed`` (the inclusions each method would lose against its own runs made again with another
noise draw, expected over the other draws: ``models.scoring.redraw_misses``; the raster's is what
``missed_vs_raster`` would be for a second raster).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.phantom import load_phantom  # noqa: E402
from models.phantom_gen import PhantomRanges, random_phantom  # noqa: E402
from models.scoring import redraw_misses  # noqa: E402
from tools.evaluate import (  # noqa: E402
    RunJob,
    RunSpec,
    add_cluster_args,
    cluster_of,
    launch_one,
    plan_runs,
    run_tasks,
    score_run,
)
from yamlstruct import Source  # noqa: E402

RASTER = REPO / "launch" / "scan_sim.yaml"
ADAPTIVE = REPO / "launch" / "scan_adaptive_sim.yaml"
SPACING_MM = 3.0
CAMERA_SPACING_MM = 4.0
"""The camera raster's press grid (launch/scan_camera_sim.yaml's spacing_mm)."""


@dataclass(frozen=True)
class Kit:
    """One probe's raster and adaptive launch files, its shipped phantom and the generated phantoms it can press."""

    raster: Path
    adaptive: Path
    shipped: Path
    ranges: PhantomRanges


KITS = {
    "airfloat": Kit(RASTER, ADAPTIVE, REPO / "phantoms" / "airfloat_tumours.yaml", PhantomRanges()),
    # the camera probe presses up to 6 mm deep, never more than 0.85 of the thinnest point: the air-float sweep's
    # 2.5-6 mm specimens give it no valid estimate (BENCHMARKS.md, specimens), so its phantoms are 8-12 mm, flat
    "camera": Kit(REPO / "launch" / "scan_camera_sim.yaml", REPO / "launch" / "scan_adaptive_camera_sim.yaml",
                  REPO / "phantoms" / "flat_26k_tumours.yaml",
                  PhantomRanges(thickness_mm=(8.0, 12.0), dome_probability=0.0)),
}
MARGIN_MM = 7.0
"""The raster region inside the true edges: the SPS ring's 6 mm radius and 1 mm for the ruler's footprint (edges to
the nearest 0.5 mm after 0.2 mm of error, models.geometry). At 6 mm the ring crossed the measured edge along whole
lines, and 17 of 63 raster runs a set ended "incomplete" (ring_off_specimen over 20 %)."""
LENGTH_MM = 6.0
"""The planner's sweep length when its run does not set ``length_mm`` (launch/scan_adaptive_sim.yaml's default)."""


def raster_probe_equivalents(spec: RunSpec, camera: bool = False, sweep_mm: float = LENGTH_MM) -> float:
    """The raster's swept length in contact over the planner's sweep length ``sweep_mm`` (its run's ``length_mm``:
    a probe is one sweep, so shorter sweeps are more of them; lines every SPACING_MM along x); for the camera probe
    its presses (a grid every CAMERA_SPACING_MM)."""
    x0, y0, x1, y1 = spec.overrides["region_mm"]
    if camera:
        return float(math.prod(math.floor(span / CAMERA_SPACING_MM + 1e-9) + 1 for span in (x1 - x0, y1 - y0)))
    lines = math.floor((x1 - x0) / SPACING_MM + 1e-9) + 1
    return float(lines * (y1 - y0) / sweep_mm)


def map_curve(spec: RunSpec, topic: str) -> list[tuple[float, float, int]]:
    """(samples, mean centroid error of found inclusions, inclusions found) for every map a run recorded on
    ``topic`` (the planner's ``planner/map`` after each probe, the raster aggregator's ``map/stiffness`` as it
    grows), detected and scored as a final map is (with the map's own baseline: the planner's final detection takes
    its stiffness-blind probes' baseline, so its curve's last point may differ from its final map's score)."""
    import msgspec

    from messages import StiffnessMap
    from models.detector import detect
    from models.scoring import score_scan
    from models.stiffness_map import MapSnapshot, to_inclusions_json
    from palpa.record.reader import iter_bag, resolve_bag_paths

    ph = load_phantom(spec.phantom)
    out = []
    for m in iter_bag(resolve_bag_paths(str(spec.run_dir / "recording.mcap"))):
        if m.topic != topic:
            continue
        b = msgspec.msgpack.decode(m.payload, type=StiffnessMap)
        xs, ys = np.array(b.x_mm), np.array(b.y_mm)
        grid = np.array(b.stiffness).reshape(len(ys), len(xs))
        snap = MapSnapshot(grid, xs, ys, np.array(b.count).reshape(grid.shape), np.array(b.spread).reshape(grid.shape),
                           float(xs[1] - xs[0]))
        dets = to_inclusions_json(detect(snap).inclusions)
        s = score_scan(ph, dets, {"stiffness": grid, "x_mm": xs, "y_mm": ys, "count": np.array(b.count).reshape(grid.shape)})
        errs = [x.centroid_error_mm for x in s.inclusions if x.found]
        out.append((float(b.samples), float(np.mean(errs)) if errs else math.nan, s.found))
    return out


def unsensed_at(spec: RunSpec, centres: list[tuple[float, float]]) -> list[bool] | None:
    """For each point, whether it lies in a cell the planner's map marks ``unsensed`` (where it said an inclusion of
    the smallest size of interest could lie unseen when it stopped; a point off the map: its nearest cell); None for
    a map without that grid."""
    grid = np.load(spec.run_dir / "map" / "map.npz")
    if "unsensed" not in grid:
        return None
    mask, xs, ys = grid["unsensed"], grid["x_mm"], grid["y_mm"]
    return [bool(mask[int(np.argmin(np.abs(ys - y))), int(np.argmin(np.abs(xs - x)))]) for x, y in centres]


def _localised(curve: list[tuple[float, float, int]], target: int) -> float:
    """The first x of ``curve`` from which on it finds at least ``target`` inclusions (nan: never for good)."""
    return next((n for i, (n, _, _) in enumerate(curve) if all(f >= target for _, _, f in curve[i:])), math.nan)


def raster_curve(spec: RunSpec, equivalents: float) -> list[tuple[float, float, int]]:
    """The raster's growing map against probes spent: its valid samples so far over its final count, times its
    probe equivalents (samples come at a steady rate while the probe sweeps)."""
    curve = map_curve(spec, "map/stiffness")
    total = max((n for n, _, _ in curve), default=0.0)
    return [(n / total * equivalents, e, f) for n, e, f in curve] if total > 0 else []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--out", type=Path, default=Path("runs/bench_adaptive"))
    ap.add_argument("--generate", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first generated phantom (a set to tune "
                    "settings on must not be the set they are judged on)")
    add_cluster_args(ap)
    ap.add_argument("--rerun", action="store_true", help="run again even the runs with a result under OUT/results")
    ap.add_argument("--adaptive-arg", action="append", default=[], metavar="NAME=VALUE",
                    help="an arg of the adaptive launch file (repeatable), e.g. epsilon=0.2")
    ap.add_argument("--no-run", action="store_true", help="only score and compare the runs already made")
    ap.add_argument("--probe", choices=sorted(KITS), default="airfloat", help="the air-float probe's sweeps (default) "
                    "or the camera probe's presses (its own launch files and thicker phantoms)")
    ap.add_argument("--only", nargs="+", default=["raster", "adaptive"],
                    choices=["raster", "adaptive", RASTER.stem, ADAPTIVE.stem],
                    help="run only these methods (the others' runs are scored if present; the air-float launch files' "
                    "names are accepted too)")
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--noise-seeds", type=int, default=1, metavar="K",
                    help="run every phantom with sensor noise seeds 0..K-1 (per-inclusion detection rates)")
    ap.add_argument("--determinism", action="store_true",
                    help="run the first phantom's adaptive launch again and compare (JSON 'deterministic')")
    ap.add_argument("--same-as", type=Path, metavar="DIR", help="compare every adaptive run with the same run "
                    "under DIR (this script's output for the same seeds, made at another time or under load): JSON "
                    "'same_as'")
    opts = ap.parse_args(argv)
    if opts.noise_seeds < 1:
        ap.error(f"--noise-seeds: at least 1 draw, got {opts.noise_seeds}")
    out: Path = opts.out.resolve()  # a worker's working directory is its own
    (out / "phantoms").mkdir(parents=True, exist_ok=True)
    kit = KITS[opts.probe]
    phantoms = [kit.shipped]
    for seed in range(opts.first_seed, opts.first_seed + opts.generate):
        path = out / "phantoms" / f"random_{seed}.yaml"
        path.write_text(yaml.safe_dump(random_phantom(seed, kit.ranges), sort_keys=False), encoding="utf-8")
        phantoms.append(path)
    # both methods on the same region: the raster's own edge margin (the SPS ring stays on the specimen)
    seeds = list(range(opts.noise_seeds))
    specs = {name: plan_runs(launch, phantoms, seeds, {}, out / name, margin_mm=MARGIN_MM, geometry_error_mm=0.2)
             for name, launch in (("raster", kit.raster), ("adaptive", kit.adaptive))}
    for item in opts.adaptive_arg:
        name, _, value = item.partition("=")
        for s in specs["adaptive"]:
            s.overrides[name] = Source.from_text(value, f"--adaptive-arg {name}").data
    # phantom by phantom, both methods: a bench cut short and run again runs only what it had not finished
    jobs = [RunJob(launch, s, True, opts.timeout) for pair in zip(specs["raster"], specs["adaptive"], strict=True)
            for name, launch, s in zip(("raster", "adaptive"), (kit.raster, kit.adaptive), pair, strict=True)
            if not opts.no_run and (name in opts.only or launch.stem in opts.only)]
    t0 = time.monotonic()
    for job, rec in zip(jobs, run_tasks(jobs, out, cluster_of(opts), rerun=opts.rerun) if jobs else [],
                        strict=True):
        print(f"{job.launch.stem} {job.spec.id}: {rec['error'] or 'done'}, "
              f"{rec['result'].get('row', {}).get('wall_s', math.nan):.0f} s", file=sys.stderr)
    wall = time.monotonic() - t0
    deterministic = _same_again(kit.adaptive, specs["adaptive"][0], opts.timeout) if opts.determinism else None
    same_as = _same_as(specs["adaptive"], opts.same_as) if opts.same_as else None
    rows: list[dict[str, Any]] = []
    rates: dict[tuple[str, int], dict[str, Any]] = {}
    curves: dict[str, list[tuple[float, float, int]]] = {}
    raster_curves: dict[str, list[tuple[float, float, int]]] = {}
    for r_spec, a_spec in zip(specs["raster"], specs["adaptive"], strict=True):
        ph = load_phantom(r_spec.phantom)
        try:
            r, r_inc = score_run(r_spec, ph)
            a, a_inc = score_run(a_spec, ph)
            plan = json.loads((a_spec.run_dir / "map" / "planner.json").read_text())
        except (OSError, ValueError, KeyError) as exc:
            print(f"{r_spec.id}: not scored ({exc})", file=sys.stderr)
            continue
        lost = [x["inclusion"] for x, y in zip(r_inc, a_inc, strict=True) if x["found"] and not y["found"]]
        missed = len(lost)
        hid = unsensed_at(a_spec, [ph.inclusions[i].center_mm for i in lost])
        for x, y in zip(r_inc, a_inc, strict=True):
            rate = rates.setdefault((r_spec.phantom.stem, x["inclusion"]), {
                "phantom": r_spec.phantom.stem, "inclusion": x["inclusion"], "radius_mm": x["radius_mm"],
                "ratio": round(x["ratio"], 3), "depth_mm": x["depth_mm"], "runs": 0, "raster": 0, "adaptive": 0})
            rate["runs"] += 1
            rate["raster"] += int(x["found"])
            rate["adaptive"] += int(y["found"])
        eq = raster_probe_equivalents(r_spec, camera=opts.probe == "camera",
                                      sweep_mm=float(a_spec.overrides.get("length_mm", LENGTH_MM)))
        rows.append({
            "run": r_spec.id, "phantom": r_spec.phantom.stem, "seed": r_spec.seed, "inclusions": r["true_inclusions"],
            "found_raster": r["found"], "found_adaptive": a["found"], "missed_vs_raster": missed,
            "probes_raster_eq": round(eq, 1), "probes_adaptive": plan["probes"], "probe_ratio": plan["probes"] / eq,
            "path_ratio": a["path_mm"] / r["path_mm"], "samples_ratio": a["probes"] / max(r["probes"], 1),
            "path_raster_mm": r["path_mm"], "path_adaptive_mm": a["path_mm"],
            "time_raster_s": r["scan_s"], "time_adaptive_s": plan["sim_s"],
            "err_raster_mm": r["mean_centroid_error_mm"], "err_adaptive_mm": a["mean_centroid_error_mm"],
            "fp_raster": r["false_positives"], "fp_adaptive": a["false_positives"],
            "sens_raster": r["sensitivity"], "sens_adaptive": a["sensitivity"],
            "spec_raster": r["specificity"], "spec_adaptive": a["specificity"],
            "iou_raster": r["iou"], "iou_adaptive": a["iou"], "stop": plan["stop"],
            "missed_unsensed": "" if hid is None else sum(hid),
        })
        try:
            curve = curves[r_spec.id] = map_curve(a_spec, "planner/map")
            raster_curves[r_spec.id] = raster_curve(r_spec, eq)
        except (OSError, ValueError) as exc:
            print(f"{a_spec.id}: no map curve ({exc})", file=sys.stderr)
            curve = []
        # localised: from this probe on, the planner's map finds at least as many inclusions as the raster's final map
        n_loc = _localised(curve, r["found"])
        r_loc = _localised(raster_curves.get(r_spec.id, []), r["found"])
        rows[-1]["probes_to_localise"] = n_loc
        rows[-1]["localise_ratio"] = n_loc / eq
        rows[-1]["raster_probes_to_localise"] = r_loc
        # in simulated seconds, pro rata: the planner's probes take about equal time, the raster samples steadily
        rows[-1]["localise_s_adaptive"] = plan["sim_s"] * n_loc / max(plan["probes"], 1)
        rows[-1]["localise_s_raster"] = r["scan_s"] * r_loc / eq
    if rows:
        with (out / "compare.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        _plot(out / "error_vs_probes.png", rows, curves, raster_curves)
    if rates:
        with (out / "inclusion_rates.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(next(iter(rates.values()))))
            w.writeheader()
            w.writerows(rates.values())
    for k in ("probe_ratio", "localise_ratio", "probes_to_localise", "raster_probes_to_localise",
              "localise_s_adaptive", "localise_s_raster", "fp_raster", "fp_adaptive", "path_ratio", "samples_ratio", "err_raster_mm",
              "err_adaptive_mm", "sens_raster",
              "sens_adaptive", "spec_raster", "spec_adaptive", "iou_raster", "iou_adaptive", "time_raster_s",
              "time_adaptive_s"):
        vals = [float(r[k]) for r in rows if isinstance(r[k], int | float) and math.isfinite(r[k])]
        print(f"{k:18s} mean {np.mean(vals):8.3f}  median {np.median(vals):8.3f}" if vals else f"{k}: -")
    complete = [r for r in rows if r["missed_vs_raster"] == 0]
    localised = [r for r in complete if math.isfinite(r["probes_to_localise"])]
    def pooled(key: str, over: list[dict[str, Any]]) -> float | None:
        return sum(r[key] for r in over) / sum(r["probes_raster_eq"] for r in over) if over else None

    def pooled_over(num: str, den: str, over: list[dict[str, Any]]) -> float | None:
        ok = [r for r in over if all(isinstance(r[k], int | float) and math.isfinite(r[k]) for k in (num, den))]
        return round(sum(r[num] for r in ok) / sum(r[den] for r in ok), 4) if ok else None

    def redraw(over: dict[tuple[str, int], dict[str, Any]], method: str) -> float | None:
        if opts.noise_seeds < 2:
            return None
        return round(redraw_misses([v[method] for v in over.values() if v["runs"] == opts.noise_seeds],
                                   opts.noise_seeds), 1)

    print(f"{len(rows)} runs scored, the sweep took {wall:.0f} s wall ({len(jobs)} launches in it)")
    print(json.dumps({"probe_ratio": pooled("probes_adaptive", complete),
                      "probe_ratio_all": pooled("probes_adaptive", rows),
                      "probe_ratio_localise": pooled("probes_to_localise", localised),
                      "time_ratio": pooled_over("time_adaptive_s", "time_raster_s", rows),
                      "path_ratio": pooled_over("path_adaptive_mm", "path_raster_mm", rows),
                      "time_ratio_localise": pooled_over("localise_s_adaptive", "time_raster_s", localised),
                      "missed_vs_raster": sum(r["missed_vs_raster"] for r in rows),
                      "missed_unsensed": (sum(r["missed_unsensed"] for r in rows)
                                          if all(r["missed_unsensed"] != "" for r in rows) else None),
                      "found_adaptive": sum(r["found_adaptive"] for r in rows),
                      "found_raster": sum(r["found_raster"] for r in rows),
                      "phantoms": len({r["phantom"] for r in rows}), "runs": len(rows),
                      "complete": len(complete), "inclusions": sum(r["inclusions"] for r in rows),
                      "noise_seeds": opts.noise_seeds,
                      "sure_raster": sum(1 for v in rates.values() if v["raster"] == v["runs"]),
                      "sure_missed": sum(1 for v in rates.values() if v["raster"] == v["runs"] > v["adaptive"]),
                      "rate_below_raster": sum(1 for v in rates.values() if v["adaptive"] < v["raster"]),
                      "rate_above_raster": sum(1 for v in rates.values() if v["adaptive"] > v["raster"]),
                      "raster_redraw_missed": redraw(rates, "raster"),
                      "adaptive_redraw_missed": redraw(rates, "adaptive"),
                      "deterministic": deterministic, "same_as": same_as}))
    return 0


def _same_again(launch: Path, spec: RunSpec, timeout_s: float) -> bool:
    """Run ``spec``'s adaptive launch once more in a sibling directory: the same probe points, the same inclusions
    and the same map (the runs are deterministic for a seed, lockstep simulated clock and all)."""
    again = RunSpec(spec.id, spec.phantom, spec.seed, spec.args, spec.overrides, spec.run_dir.with_name(spec.id + "-again"))
    ran = launch_one(launch, again, in_process=True, timeout_s=timeout_s)
    if ran["exit_code"] != 0:
        return False
    same_points, same_found, same_map = _same_outputs(spec.run_dir, again.run_dir)
    print(f"determinism ({spec.id}): points {same_points}, inclusions {same_found}, map {same_map}", file=sys.stderr)
    return same_points and same_found and same_map


def _same_outputs(run_a: Path, run_b: Path) -> tuple[bool, bool, bool]:
    """Whether two adaptive runs' outputs agree: their probe points, their inclusions, their maps."""
    a, b = run_a / "map", run_b / "map"
    same_points = json.loads((a / "planner.json").read_text())["points"] == \
        json.loads((b / "planner.json").read_text())["points"]
    same_found = (a / "inclusions.json").read_text() == (b / "inclusions.json").read_text()
    with np.load(a / "map.npz") as ga, np.load(b / "map.npz") as gb:
        same_map = bool(np.array_equal(ga["stiffness"], gb["stiffness"], equal_nan=True))
    return same_points, same_found, same_map


def _same_as(specs: list[RunSpec], other: Path) -> dict[str, Any]:
    """Every adaptive run here against the run of the same phantom and draw under ``other`` (another output
    directory of this script over the same seeds, made at another time or under other load): how many agree in
    points, inclusions and map, and which do not."""
    runs, differ = 0, []
    for spec in specs:
        there = other / "adaptive" / "runs" / spec.id
        if not (spec.run_dir / "map" / "planner.json").exists() or not (there / "map" / "planner.json").exists():
            continue
        runs += 1
        if not all(_same_outputs(spec.run_dir, there)):
            differ.append(spec.id)
    return {"runs": runs, "same": runs - len(differ), "differ": differ}


def _plot(path: Path, rows: list[dict[str, Any]], curves: dict[str, list[tuple[float, float, int]]],
          raster_curves: dict[str, list[tuple[float, float, int]]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), dpi=100)
    for i, row in enumerate(rows):
        for curve_set, colour, label in ((raster_curves, "tab:red", "raster (its map as it grows)"),
                                         (curves, "tab:blue", "adaptive (its map after each probe)")):
            curve = curve_set.get(row["run"])
            if curve:
                n, err, found = zip(*curve, strict=True)
                ax1.plot(n, err, color=colour, alpha=0.35, lw=1, label=label if i == 0 else None)
                ax2.plot(n, np.array(found) / max(row["inclusions"], 1), color=colour, alpha=0.35, lw=1,
                         label=label if i == 0 else None)
    ax1.scatter([r["probes_adaptive"] for r in rows], [r["err_adaptive_mm"] for r in rows], color="tab:blue",
                marker="o", s=18, zorder=3, label="adaptive, where its stop rule stopped")
    ax1.scatter([r["probes_raster_eq"] for r in rows], [r["err_raster_mm"] for r in rows], color="tab:red",
                marker="s", s=18, zorder=3, label="raster, final map")
    ax1.set(xlabel="probes spent (6 mm sweeps; raster: swept length / 6 mm)", ylabel="mean centroid error (mm)",
            ylim=(0, 6))
    ax2.set(xlabel="probes spent", ylabel="fraction of true inclusions found")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
