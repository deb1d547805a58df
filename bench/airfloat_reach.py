"""How far past its edge does a buried inclusion raise the air-float probe's map? Measured on raster scans.

The adaptive planner (models.adaptive_detect, models.adaptive_cover) stops covering when an inclusion of interest
could hide only with a small chance; it counts an inclusion of radius r as *sensed* by any measured cell whose centre
lies within ``reach_mm + (r - 2.5)`` of the inclusion's centre (defaults: r + 1.5 mm). This script checks that
model against what the whole simulated pipeline made of real scans (world -> probe -> fibre -> estimator -> map),
with nothing from the planner: the raster's maps of the bench sets (``bench/adaptive.py`` output directories), each
map's measured cells against the phantom's truth.

For every raster map: the baseline is the median of cells farther than ``--far-mm`` from every inclusion's edge and
the noise scale their robust spread (1.4826 MAD) over the baseline; a cell reads ``rel = value / baseline - 1``.
For every inclusion, the cells farther than ``--far-mm`` from the others' edges are binned by their centre's
distance past its edge, ``e = distance - r`` (0.5 mm bins), and the mean ``rel`` in each bin is kept per
inclusion, over all the draws of its phantom. The *suspect bar* is where the planner starts resolving a candidate,
``suspect x max(0.2, k x noise scale)`` (its defaults: 0.6, 4). An inclusion is sensed at distance e when its mean
reading there clears the bar; its *reach* is the largest e from 0 outward up to which every bin does.

Prints a table by depth and radius (the inclusions the raster's map found in every draw, as models.scoring scores
a scan) and a JSON line:
``sensed_at_model_reach`` (fraction whose mean reading at the model's reach clears the bar) and the reach's
quantiles per depth class.

    PYTHONPATH=$PWD .venv/bin/python bench/airfloat_reach.py runs/m8000 runs/m9000 ... [--phantoms DIR ...]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.phantom import Phantom, load_phantom  # noqa: E402

BIN_MM = 0.5
EDGES = np.arange(-1.0, 5.01, BIN_MM)  # distance past the edge; cells over the inclusion's rim and beyond
DEPTHS = [(0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.6)]
RADII = [(2.5, 4.0), (4.0, 5.5), (5.5, 7.1)]


def find_phantom(name: str, dirs: list[Path]) -> Path | None:
    """The phantom file ``name`` in the first of ``dirs`` that holds it."""
    return next((d / f"{name}.yaml" for d in dirs if (d / f"{name}.yaml").is_file()), None)


def profiles(map_npz: Path, ph: Phantom, far_mm: float, k: float, suspect: float
             ) -> tuple[list[np.ndarray], float] | None:
    """Per inclusion, the mean ``rel`` of the map's measured cells in each bin of ``EDGES`` (nan: no cell), and the
    map's suspect bar; None when too few cells lie far from every inclusion to tell the baseline."""
    with np.load(map_npz) as g:
        v, xs, ys, count = g["stiffness"], g["x_mm"], g["y_mm"], g["count"]
    measured = np.isfinite(v) & (count > 0)
    gx, gy = np.meshgrid(xs, ys)
    past = [np.hypot(gx - inc.center_mm[0], gy - inc.center_mm[1]) - inc.radius_mm for inc in ph.inclusions]
    nearest = np.min(past, axis=0) if past else np.full(v.shape, np.inf)
    far = measured & (nearest > far_mm)
    if far.sum() < 10:
        return None
    base = float(np.median(v[far]))
    scale = 1.4826 * float(np.median(np.abs(v[far] - base))) / base
    rel = v / base - 1.0
    bar = suspect * max(0.2, k * scale)
    out = []
    for i, e in enumerate(past):
        others = [p for j, p in enumerate(past) if j != i]
        alone = measured & (np.min(others, axis=0) > far_mm if others else True)
        means = np.full(EDGES.size - 1, np.nan)
        for b in range(EDGES.size - 1):
            sel = alone & (e >= EDGES[b]) & (e < EDGES[b + 1])
            if sel.any():
                means[b] = float(np.mean(rel[sel]))
        out.append(means)
    return out, bar


def raster_found(map_dir: Path, ph: Phantom) -> list[bool]:
    """For each of the phantom's inclusions, whether the raster's map found it (models.scoring, as bench/adaptive.py
    scores a run)."""
    from models.scoring import score_scan

    with np.load(map_dir / "map.npz") as g:
        grid = {k: g[k] for k in ("stiffness", "x_mm", "y_mm", "count")}
    dets = json.loads((map_dir / "inclusions.json").read_text())
    return [i.found for i in score_scan(ph, dets, grid).inclusions]


def reach_of(margin: np.ndarray) -> float:
    """The largest distance past the edge up to which every bin with data clears the bar (margin >= 0); -inf when
    even the rim does not."""
    reach = -math.inf
    for b, m in enumerate(margin):
        if math.isnan(m):
            continue
        if m < 0:
            break
        reach = float(EDGES[b + 1])
    return reach


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sets", type=Path, nargs="+", help="bench/adaptive.py output directories (their raster/runs)")
    ap.add_argument("--phantoms", type=Path, nargs="*", default=[], help="more directories to look for phantoms in")
    ap.add_argument("--far-mm", type=float, default=6.0)
    ap.add_argument("--k", type=float, default=4.0)
    ap.add_argument("--suspect", type=float, default=0.6)
    ap.add_argument("--model-past-edge-mm", type=float, default=1.5, help="the planner's reach past the edge")
    args = ap.parse_args()
    dirs = [s / "phantoms" for s in args.sets] + list(args.phantoms) + [REPO / "phantoms"]
    # per (set, phantom, inclusion): margins over the bar, one row per draw
    margins: dict[tuple[str, str, int], list[np.ndarray]] = defaultdict(list)
    meta: dict[tuple[str, str, int], tuple[float, float, float]] = {}
    missed: set[tuple[str, str, int]] = set()   # by the raster in some draw
    for s in args.sets:
        for run in sorted((s / "raster" / "runs").glob("*-s*")):
            name = run.name.rsplit("-s", 1)[0]
            npz, ph = run / "map" / "map.npz", find_phantom(name, dirs)
            if not npz.is_file() or ph is None:
                continue
            phantom = load_phantom(ph)
            got = profiles(npz, phantom, args.far_mm, args.k, args.suspect)
            if got is None:
                continue
            means, bar = got
            incs = phantom.inclusions
            found = raster_found(run / "map", phantom)
            for i, m in enumerate(means):
                key = (s.name, name, i)
                if not found[i]:
                    missed.add(key)
                margins[key].append(m - bar)
                meta[key] = (incs[i].radius_mm, incs[i].depth_mm, incs[i].youngs_modulus_kpa)
    model_bin = int(np.searchsorted(EDGES, args.model_past_edge_mm - 1e-9)) - 1
    rows = []
    for key, ms in margins.items():
        with np.errstate(all="ignore"):
            mean = np.nanmean(np.array(ms), axis=0)
        r, d, _ = meta[key]
        rows.append({"key": key, "radius": r, "depth": d, "sure": key not in missed, "reach": reach_of(mean),
                     "at_model": float(mean[model_bin])})
    judged = [r for r in rows if r["sure"] and not math.isnan(r["at_model"])]
    print(f"{len(rows)} inclusions over {len(args.sets)} sets; {len(judged)} found by the raster in every draw and "
          f"measured {EDGES[model_bin]:g}-{EDGES[model_bin + 1]:g} mm past their edge (the model's reach)")
    print("\n| depth (mm) | radius (mm) | inclusions | sensed at the model's reach | reach past the edge, median "
          "(10th pct) |\n|---|---|---|---|---|")
    summary = {}
    for d0, d1 in DEPTHS:
        for r0, r1 in RADII + [(2.5, 7.1)]:
            grp = [r for r in judged if d0 <= r["depth"] < d1 and r0 <= r["radius"] < r1]
            if not grp:
                continue
            ok = sum(r["at_model"] >= 0 for r in grp)
            reach = np.maximum([r["reach"] for r in grp], EDGES[0])
            label = "all" if (r0, r1) == (2.5, 7.1) else f"{r0:g}-{r1:g}"
            print(f"| {d0:g}-{d1:g} | {label} | {len(grp)} | {ok} ({100 * ok / len(grp):.0f} %) | "
                  f"{np.median(reach):.1f} ({np.percentile(reach, 10):.1f}) |")
            if label == "all":
                summary[f"{d0:g}-{d1:g}"] = {"n": len(grp), "sensed": ok, "reach_median": float(np.median(reach)),
                                             "reach_p10": float(np.percentile(reach, 10))}
    ok_all = sum(r["at_model"] >= 0 for r in judged)
    reach = np.maximum([r["reach"] for r in judged], EDGES[0]) if judged else np.array([np.nan])
    quintiles = [round(float(q), 2) for q in np.percentile(reach, [10, 30, 50, 70, 90])]
    spread = [round(q - args.model_past_edge_mm, 2) for q in quintiles]
    print(f"\nreach past the edge, quintiles' middles (10/30/50/70/90th pct): {quintiles}; as offsets from the "
          f"model's {args.model_past_edge_mm:g} mm (reach_spread_mm): {spread}")
    hiding = miss_at_stop(args.sets, spread)
    if hiding:
        claimed, measured = np.array(hiding).T
        print(f"the planner's {claimed.size} runs: the chance an inclusion of interest hid when it stopped, by its "
              f"reach model {claimed.mean():.4f} (max {claimed.max():.4f}), over the measured reaches "
              f"{measured.mean():.4f} (max {measured.max():.4f})")
    print(json.dumps({"inclusions": len(judged), "sensed_at_model_reach": ok_all / max(len(judged), 1),
                      "model_past_edge_mm": args.model_past_edge_mm, "reach_quintiles_mm": quintiles,
                      "reach_spread_mm": spread, "by_depth": summary,
                      "miss_at_stop_model": float(np.mean([h[0] for h in hiding])) if hiding else None,
                      "miss_at_stop_measured": float(np.mean([h[1] for h in hiding])) if hiding else None}))
    return 0


def miss_at_stop(sets: list[Path], spread: list[float]) -> list[tuple[float, float]]:
    """For every adaptive run of ``sets`` (their ``adaptive/runs``), the chance that an inclusion of interest lay
    where the planner's final map had sensed nothing, by the planner's default reach model and with the measured
    ``spread`` of reaches instead (models.adaptive_cover.miss_probability over the map's measured cells; the
    planner counts a sweep's whole path, so this is a little above its own figure)."""
    from models.adaptive import PlannerConfig
    from models.adaptive_cover import miss_probability

    out = []
    for s in sets:
        for run in sorted((s / "adaptive" / "runs").glob("*-s*")):
            if not (run / "map" / "map.npz").is_file():
                continue
            with np.load(run / "map" / "map.npz") as g:
                measured, xs, ys = g["count"] > 0, g["x_mm"], g["y_mm"]
            res = float(xs[1] - xs[0])
            cfg = PlannerConfig((float(xs[0]), float(ys[0]), float(xs[-1]) + res, float(ys[-1]) + res))
            with_spread = PlannerConfig(cfg.region_mm, reach_spread_mm=tuple(spread))
            out.append((miss_probability(measured, res, cfg.reaches()),
                        miss_probability(measured, res, with_spread.reaches())))
    return out


if __name__ == "__main__":
    sys.exit(main())
