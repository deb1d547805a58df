"""What could this scan have found: the map detector's sensitivity against its false positives per map (issue 37).

Reads the saved maps of ``tools.evaluate`` runs on generated phantoms (each folder's ``runs.json`` names every
run's phantom), runs models.detector.detect on each map at a range of false-alarm rates per map (the detector's
one knob: its threshold), scores each with models.scoring, and draws sensitivity (true inclusions found) against
false positives per map, by inclusion radius, stiffness ratio and depth, the default operating point marked. Blank
specimens' folders (``--blank``) add their maps to the false positives' count (they have nothing to find).

    python -m tools.evaluate launch/scan_sim.yaml --generate 40 --phantom-seed 20 -o runs/roc --jobs 2
    .venv/bin/python bench/detector_roc.py runs/eval20 runs/roc --blank runs/blank_flat runs/blank_dome

Writes docs/img/detector_roc.png and prints one JSON line (per group and operating point: found, total, false
positives, maps).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.detector import DetectorConfig, detect  # noqa: E402
from models.phantom import Phantom, load_phantom  # noqa: E402
from models.scoring import score_scan  # noqa: E402
from models.stiffness_map import MapSnapshot, to_inclusions_json  # noqa: E402
from nodes.mapping.map_output import read_map  # noqa: E402

RATES = (0.9, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01, 3e-3, 1e-3, 1e-4, 1e-6)
GROUPS: dict[str, tuple[str, list[tuple[float, float]]]] = {
    "radius (mm)": ("radius_mm", [(2.5, 4.0), (4.0, 5.5), (5.5, 7.01)]),
    "stiffness ratio": ("ratio", [(1.5, 2.5), (2.5, 4.0), (4.0, 6.01)]),
    "depth of its top (mm)": ("depth_mm", [(0.5, 1.2), (1.2, 1.9), (1.9, 2.51)]),
}


def runs_of(folder: Path) -> list[tuple[MapSnapshot, dict[str, Any], Phantom | None]]:
    """Every scored run of an evaluate folder: its map, its map.npz arrays and its phantom."""
    out = []
    for row in json.loads((folder / "runs.json").read_text()):
        npz = folder / "runs" / row["run"] / "map" / "map.npz"
        if row.get("error") or not npz.exists():
            continue
        with np.load(npz) as d:
            arrays = dict(d)
        phantom = Path(row["phantom"])   # tools.evaluate names a generated one relative to the folder
        out.append((read_map(npz), arrays, load_phantom(phantom if phantom.exists() else folder / phantom)))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sets", type=Path, nargs="+", help="evaluate output folders of generated phantoms")
    ap.add_argument("--blank", type=Path, nargs="*", default=[], help="evaluate folders of blank specimens")
    ap.add_argument("-o", "--output", type=Path, default=REPO / "docs" / "img" / "detector_roc.png")
    args = ap.parse_args()
    runs = [r for f in args.sets for r in runs_of(f)]
    blanks = [r for f in args.blank for r in runs_of(f)]
    base = DetectorConfig()
    # per operating point: per true inclusion (its radius, ratio, depth, found) and the false positives
    table: dict[float, dict[str, Any]] = {}
    for rate in RATES:
        cfg = replace(base, false_alarm_per_map=rate)
        found: list[tuple[float, float, float, bool]] = []
        fps = 0
        for snap, arrays, ph in runs + blanks:
            assert ph is not None
            score = score_scan(ph, to_inclusions_json(detect(snap, cfg).inclusions), arrays)
            fps += len(score.false_positives)
            for s in score.inclusions:
                found.append((s.radius_mm, s.ratio, ph.inclusions[s.index].depth_mm, s.found))
        table[rate] = {"inclusions": found, "false_positives": fps, "maps": len(runs) + len(blanks)}
    summary: dict[str, Any] = {"maps": len(runs) + len(blanks), "blank_maps": len(blanks), "rates": list(RATES),
                               "default_rate": base.false_alarm_per_map, "groups": {}}
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(GROUPS), figsize=(4.6 * len(GROUPS), 4.0), sharey=True)
    for ax, (title, (key, bins)) in zip(axes, GROUPS.items(), strict=True):
        col = ("radius_mm", "ratio", "depth_mm").index(key)
        summary["groups"][title] = {}
        for lo, hi in [(0.0, 99.0), *bins]:
            label = "all" if hi == 99.0 else f"{lo:g}-{min(hi, round(hi, 1)):g}"
            xs, ys, counts = [], [], []
            for rate in RATES:
                rows = [r for r in table[rate]["inclusions"] if lo <= r[col] < hi]
                n_found = sum(r[3] for r in rows)
                xs.append(table[rate]["false_positives"] / table[rate]["maps"])
                ys.append(n_found / len(rows) if rows else np.nan)
                counts.append([n_found, len(rows), table[rate]["false_positives"]])
            summary["groups"][title][label] = counts
            style = {"color": "black", "lw": 2.2} if label == "all" else {"lw": 1.4}
            ax.plot(xs, ys, marker="o", ms=3, label=f"{label} ({counts[0][1]})", **style)
            i = RATES.index(base.false_alarm_per_map)
            ax.plot(xs[i], ys[i], "s", mfc="none", mec="red", ms=9)
        ax.set_xscale("symlog", linthresh=0.01)
        ax.set_xlabel("false positives per map")
        ax.set_title(f"by {title}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    axes[0].set_ylabel("sensitivity (true inclusions found)")
    fig.suptitle(f"Map detector on {len(runs)} generated scans + {len(blanks)} blank ones (air-float sweep, "
                 f"3 mm lines): one point per false-alarm rate {RATES[0]:g}..{RATES[-1]:g}; red: the default "
                 f"{base.false_alarm_per_map:g}", fontsize=9)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=110, bbox_inches="tight")
    print(f"chart {args.output}")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
