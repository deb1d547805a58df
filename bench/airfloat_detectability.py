"""Which buried inclusions can the air-float sweep find at all? A contrast-vs-noise chart from the world directly.

Full scans are too slow for a sweep of radius x ratio x depth, so this asks the FE-grounded world
(``models.world.TissueWorld``) what the probe would read: at the sweep's force (the paper's eq. 4 line at
``--pressure-kpa``) the indenter sinks d_bg into plain tissue and d_inc over an inclusion's axis (and 2 mm off
it); the estimator's eq. 7 turns both into moduli, and their ratio is the contrast the map would show. An inclusion
is *detectable* when that contrast exceeds a fixed-ratio threshold (the rule of the detector before issue 37: 1 +
max(0.2, k_mad x the map's robust relative noise); what today's detector finds on scans is bench/detector_roc.py's
chart) on its axis and 2 mm off it (two 2 mm cells, the smallest region the
detector keeps). The layer is 3.68 mm thick (the dome at the paper's tumours) unless ``--thickness-mm``.
Writes docs/img/detectability_airfloat.png and prints one JSON line.

    .venv/bin/python bench/airfloat_detectability.py [--noise-rel 0.05] [--pressure-kpa 36 40]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.contact import corrected_modulus  # noqa: E402
from models.phantom import parse_phantom  # noqa: E402
from models.world import TissueWorld  # noqa: E402

RADII = np.array([2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
RATIOS = np.array([1.5, 2.0, 3.0, 4.0, 6.0, 8.0])
DEPTHS = [1.0, 2.0, 3.0]
DEMO = [(6, 6), (5, 4), (4, 2), (3, 3)]  # the paper's Fig. 12 tumours (radius, ratio), 2 mm deep
E_BG = 26.4


def world(radius: float, ratio: float, depth: float, thickness: float) -> TissueWorld:
    return TissueWorld(parse_phantom({
        "size_mm": [60, 60], "thickness_mm": thickness, "youngs_modulus_kpa": E_BG,
        "inclusions": [{"center_mm": [30, 30], "radius_mm": float(radius), "depth_mm": float(depth),
                        "youngs_modulus_kpa": float(E_BG * ratio)}]}))


def contrast(force: float, radius: float, ratio: float, depth: float, thickness: float) -> tuple[float, float]:
    """Apparent modulus contrast (eq. 7 over the inclusion / over plain tissue) on the axis and 2 mm off it."""
    w = world(radius, ratio, depth, thickness)
    x = np.array([30.0, 32.0, 5.0])  # on the axis, 2 mm off, far away (plain tissue)
    d = np.asarray(w.depth_mm(x, np.full(3, 30.0), np.full(3, force), indenter_radius_mm=4.0), dtype=float)
    e = np.asarray(corrected_modulus(force, d, 4.0, thickness), dtype=float)
    return float(e[0] / e[2]), float(e[1] / e[2])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--noise-rel", type=float, default=0.05, help="the map's robust relative noise (demo scan)")
    ap.add_argument("--k-mad", type=float, default=4.0)
    ap.add_argument("--pressure-kpa", type=float, nargs="+", default=[36.0, 40.0])
    ap.add_argument("--thickness-mm", type=float, default=3.68)
    ap.add_argument("-o", "--output", type=Path, default=REPO / "docs" / "img" / "detectability_airfloat.png")
    args = ap.parse_args()
    t0 = time.perf_counter()
    threshold = 1.0 + max(0.2, args.k_mad * args.noise_rel)
    results: dict[str, list[list[list[float]]]] = {}
    for p in args.pressure_kpa:
        force = 7.59 * p / 100.0 - 2.34
        for depth in DEPTHS:
            grid = [[contrast(force, r, k, depth, args.thickness_mm) for k in RATIOS] for r in RADII]
            results[f"{p:g} kPa, {depth:g} mm deep"] = [[list(c) for c in row] for row in grid]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(args.pressure_kpa), len(DEPTHS), figsize=(4.2 * len(DEPTHS),
                             3.6 * len(args.pressure_kpa)), squeeze=False, sharex=True, sharey=True)
    for i, p in enumerate(args.pressure_kpa):
        for j, depth in enumerate(DEPTHS):
            c = np.array(results[f"{p:g} kPa, {depth:g} mm deep"])  # (radius, ratio, [axis, off])
            ax = axes[i][j]
            im = ax.pcolormesh(np.arange(RADII.size + 1) - 0.5, np.arange(RATIOS.size + 1) - 0.5, c[:, :, 0].T,
                               cmap="viridis", vmin=1.0, vmax=max(2.0, float(c[:, :, 0].max())))
            for a in range(RADII.size):
                for b in range(RATIOS.size):
                    ok = c[a, b, 0] > threshold and c[a, b, 1] > threshold
                    ax.text(a, b, f"{c[a, b, 0]:.2f}" + ("" if ok else "\n✗"), ha="center", va="center",
                            fontsize=7, color="white" if c[a, b, 0] < 1.5 else "black")
            if depth == 2.0:
                for r, k in DEMO:
                    ax.plot(list(RADII).index(r), list(RATIOS).index(k), "s", mfc="none", mec="red", ms=18)
            ax.set_title(f"{p:g} kPa (F {7.59 * p / 100 - 2.34:.2f} N), top {depth:g} mm deep", fontsize=9)
            ax.set_xticks(range(RADII.size), [f"{r:g}" for r in RADII])
            ax.set_yticks(range(RATIOS.size), [f"{k:g}" for k in RATIOS])
            if i == len(args.pressure_kpa) - 1:
                ax.set_xlabel("inclusion radius (mm)")
            if j == 0:
                ax.set_ylabel("stiffness ratio")
    fig.colorbar(im, ax=axes, label="apparent contrast (eq. 7 over inclusion / plain tissue)")
    fig.suptitle(f"Air-float sweep detectability on a {args.thickness_mm:g} mm layer (world: FE tables). ✗: "
                 f"contrast below {threshold:.2f} (map threshold at {100 * args.noise_rel:.0f} % noise) on the axis "
                 "or 2 mm off it; red squares: Fig. 12's tumours", fontsize=9)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=110, bbox_inches="tight")
    print(f"threshold {threshold:.3f}; chart {args.output}; wall {time.perf_counter() - t0:.1f} s")
    print(json.dumps({"threshold": threshold, "radii": RADII.tolist(), "ratios": RATIOS.tolist(),
                      "contrast": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
