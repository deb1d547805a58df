"""The detector's false-alarm law, measured on blank specimens (issue 37): derives models.detector's GUMBEL_LOC,
GUMBEL_SCALE and REFERENCE_AREA_MM2 (the air-float probe's sweep maps), or CAMERA_GUMBEL_* (the camera probe's
press grids): each probe's law from its own blank maps (models.false_alarm.FALSE_ALARM_LAWS).

Scan the blank specimens once (a flat 3 mm sheet and the demo's dome without tumours, twenty noise draws each: the
device's errors, the sensor noise and the thickness measurement all drawn from the seed):

    python -m tools.evaluate launch/scan_sim.yaml --phantom phantoms/blank/flat_3mm.yaml \\
        --phantom phantoms/blank/dome_4_2.yaml --seeds $(seq 0 19) -o runs/blank --jobs 1

then fit the law of each map's largest significance the detector could report (models.detector.peak_significance:
the matched filter's largest output over its scales and the map's cells, an edge row off the specimen left out) on
the saved maps:

    .venv/bin/python bench/detector_calibration.py runs/blank

The camera probe's, the same way on its blank specimens (its scan target without tumours, and a 12-8 mm dome):

    python -m tools.evaluate launch/scan_camera_sim.yaml --phantom phantoms/blank/camera_flat_10mm.yaml \
        --phantom phantoms/blank/camera_dome_12_8.yaml --seeds $(seq 0 19) -o runs/camblank --serial
    .venv/bin/python bench/detector_calibration.py runs/camblank

The adaptive planner's maps (issue 41) are partial: its lattice, what it measured around suspects, the GP's mean
within ``fill_mm``. Their noise is not a whole map's, so they get a law of their own (``ADAPTIVE_*``; a planner held to
a probe budget, ``--arg budget_fraction=...``, its own: ``BUDGET_*``), fitted on the planner's final detections of
the same blank specimens as its planner.json states them:

    python -m tools.evaluate launch/scan_adaptive_sim.yaml --phantom phantoms/blank/flat_3mm.yaml \
        --phantom phantoms/blank/dome_4_2.yaml --seeds $(seq 0 19) --margin 7 -o runs/blank_adaptive --workers 1
    .venv/bin/python bench/detector_calibration.py runs/blank_adaptive --planner

Which probe's law is fitted is read from the maps (map.npz's ``model``, else its unit); all maps must agree.

The largest of many weakly dependent significances follows a Gumbel law whose location grows as
``scale * ln(area)``; the fit is maximum likelihood with each map's valid area as an offset. The candidates the
detector leaves out of its background depend on its threshold, so the fit is repeated with the constants it found
until they stop moving. Prints the constants, the per-map maxima, the threshold at the detector's default
false-alarm rate and how many of these blank maps it would call anything on; the constants go into
models/false_alarm.py by hand (the printed result goes into BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.detector import (  # noqa: E402
    DetectorConfig,
    detect,
    false_alarm_law,
    fit_false_alarm_law,
    peak_significance,
    threshold_for,
)
from models.stiffness_map import MapSnapshot  # noqa: E402
from nodes.mapping.map_output import map_model, read_map  # noqa: E402

_NAMES = {"airfloat": "", "multi_indenter": "CAMERA_"}
"""Prefix of each probe's constants in models/false_alarm.py."""


def peaks(maps: list[MapSnapshot], cfg: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Each map's largest significance and its valid area (mm²)."""
    top, area = [], []
    for snap in maps:
        det = detect(snap, cfg)
        top.append(peak_significance(det))
        area.append(float(np.isfinite(det.significance).sum()) * snap.resolution_mm**2)
    return np.array(top), np.array(area)


def planner_law(runs: list[Path]) -> int:
    """``--planner``: the law of the adaptive planner's own maps, from the final detection each run's planner.json
    states (its largest significance and valid area: models.adaptive_detect's detection, the planner's fair cells and
    blind cells as the planner had them; a re-detection of map.npz alone would not know them)."""
    files = sorted(p for r in runs for p in r.glob("runs/*/map/planner.json") if p.parent.parent.name != "latest")
    found = [json.loads(f.read_text(encoding="utf-8")).get("detection") or {} for f in files]
    if not files or not all("peak_significance" in d for d in found):
        raise SystemExit(f"need runs/*/map/planner.json with a 'detection' under {', '.join(map(str, runs))}")
    budgeted = {float(d.get("budget_fraction", 0.0)) > 0 for d in found}
    if len(budgeted) != 1:
        raise SystemExit("the runs mix budgeted and unbudgeted planners: each has a law of its own "
                         "(models.false_alarm.PARTIAL_MAP_LAWS), fit them apart")
    name = "BUDGET" if budgeted.pop() else "ADAPTIVE"
    top = np.array([d["peak_significance"] for d in found])
    area = np.array([d["area_mm2"] for d in found])
    ref_area = float(np.median(area))
    loc, scale = fit_false_alarm_law(top, area, ref_area)
    cfg = replace(DetectorConfig(), gumbel=(loc, scale, ref_area))
    over = [t > threshold_for(a, cfg) for t, a in zip(top, area, strict=True)]
    was = [t > d["threshold_snr"] for t, d in zip(top, found, strict=True)]
    print(f"{len(files)} blank adaptive maps; largest significance per map: median {np.median(top):.2f}, range "
          f"{top.min():.2f}..{top.max():.2f} σ; valid area {area.min():.0f}..{area.max():.0f} mm²")
    for f, t, a in zip(files, top, area, strict=True):
        print(f"  {f.parent.parent.name:24s} {t:5.2f} ({a:.0f} mm²)")
    print(f"{name}_GUMBEL_LOC = {loc:.3f}\n{name}_GUMBEL_SCALE = {scale:.3f}\n"
          f"ADAPTIVE_REFERENCE_AREA_MM2 = {ref_area:.0f}")
    print(f"maps over the threshold they were detected with: {sum(was)} of {len(files)}; over this law's at "
          f"{100 * cfg.false_alarm_per_map:g} %: {sum(over)}")
    print(json.dumps({"model": name.lower(), "loc": loc, "scale": scale, "ref_area_mm2": ref_area,
                      "maxima": [round(float(t), 3) for t in top], "maps_over_their_threshold": int(sum(was))}))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", type=Path, nargs="+", help="evaluate output folders (their runs/*/map/map.npz)")
    ap.add_argument("--rounds", type=int, default=4, help="refits with the constants found (candidates move)")
    ap.add_argument("--planner", action="store_true", help="the adaptive planner's maps: fit from planner.json")
    args = ap.parse_args()
    if args.planner:
        return planner_law(args.runs)
    files = sorted(p for r in args.runs for p in r.glob("runs/*/map/map.npz") if p.parent.parent.name != "latest")
    if not files:
        raise SystemExit(f"no runs/*/map/map.npz under {', '.join(map(str, args.runs))}")
    models = {map_model(f) for f in files}
    if len(models) != 1 or next(iter(models)) not in _NAMES:
        raise SystemExit(f"the maps must all be of one probe with a law in models.false_alarm ({', '.join(_NAMES)}): "
                         f"they are of {', '.join(sorted(m or '?' for m in models))}")
    model = models.pop()
    maps = [read_map(f) for f in files]
    cfg = DetectorConfig(gumbel=false_alarm_law(model) or DetectorConfig().gumbel)
    ref_area = cfg.gumbel[2]
    for _ in range(args.rounds):
        top, area = peaks(maps, cfg)
        ref_area = float(np.median(area))
        loc, scale = fit_false_alarm_law(top, area, ref_area)
        cfg = replace(cfg, gumbel=(loc, scale, ref_area))
    top, area = peaks(maps, cfg)
    calls = sum(bool(detect(m, cfg).inclusions) for m in maps)
    print(f"{len(maps)} blank {model} maps; largest significance per map: median {np.median(top):.2f}, "
          f"range {top.min():.2f}..{top.max():.2f} σ; valid area {area.min():.0f}..{area.max():.0f} mm²")
    for f, t in zip(files, top, strict=True):
        print(f"  {f.parent.parent.name:24s} {t:5.2f}")
    pre = _NAMES[model]
    print(f"{pre}GUMBEL_LOC = {cfg.gumbel[0]:.3f}\n{pre}GUMBEL_SCALE = {cfg.gumbel[1]:.3f}\n"
          f"{pre}REFERENCE_AREA_MM2 = {ref_area:.0f}")
    for p in (0.05, 0.01, 0.001):
        print(f"threshold at {100 * p:g} % false alarms per map of the reference area: "
              f"{threshold_for(ref_area, replace(cfg, false_alarm_per_map=p)):.2f} σ")
    print(f"blank maps with any detection at the default {100 * cfg.false_alarm_per_map:g} %: {calls} of {len(maps)}")
    print(json.dumps({"model": model, "loc": cfg.gumbel[0], "scale": cfg.gumbel[1], "ref_area_mm2": ref_area,
                      "maxima": [round(float(t), 3) for t in top], "maps_with_detection": calls}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
