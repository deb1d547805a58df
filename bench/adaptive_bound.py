"""How many of the raster's finds a planner at a given probe ratio must leave unsensed: a bound from geometry alone.

    .venv/bin/python bench/adaptive_bound.py runs/bench_adaptive            # an output of bench/adaptive.py
    .venv/bin/python bench/adaptive_bound.py OUT --reach-mm 2.0 --ratios 0.15 0.2

A sweep senses an inclusion of radius ``r`` only if it passes within ``d = r + reach`` of its centre (the excess
stiffness reaches ``reach`` past the edge: median 2 mm, a quarter of them 1 mm or less, bench/airfloat_reach.py; the
planner's own model takes 1.5 mm). A planner whose probes add up to a fraction ``f`` of the raster's swept length
(``probe_ratio``, bench/adaptive.py: one probe is one sweep of ``sweep_mm``) makes ``f * area / (spacing * sweep)``
sweeps, each sensing at most a stadium of ``2 d sweep + pi d^2``; with no overlap at all (the most any arrangement
can do) an inclusion whose centre is uniform over the region hides with probability at least
``max(0, 1 - f (2 d + pi d^2 / sweep) / spacing)`` (``spacing``: the raster's, 3 mm), whatever the planner decides
afterwards, since it decides on what it has sensed. The ends of short sweeps matter: parallel lines the same length
would sense half as much.

Summed over the inclusion-draws the raster found (``inclusion_rates.csv``: each true inclusion's radius and the
number of draws the raster found it in), that is the number of the raster's finds a planner at ratio ``f`` leaves
unsensed in expectation, at the least. Compare it with ``missed_vs_raster``: what a planner misses beyond it, it
sensed and could not tell from noise (a matter of the density of its samples over the inclusion, not of where it
swept). The last line is JSON.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path


def hide_probability(radius_mm: float, reach_mm: float, ratio: float, spacing_mm: float, sweep_mm: float) -> float:
    """A lower bound on the probability that an inclusion of ``radius_mm``, its centre uniform, lies farther than
    its radius plus ``reach_mm`` from every sweep of a planner spending ``ratio`` of a ``spacing_mm`` raster's
    swept length in sweeps of ``sweep_mm``."""
    d = radius_mm + reach_mm
    return max(0.0, 1.0 - ratio * (2.0 * d + math.pi * d * d / sweep_mm) / spacing_mm)


def expected_unsensed(rows: list[dict[str, str]], reach_mm: float, ratio: float, spacing_mm: float,
                      sweep_mm: float) -> float:
    """The raster's finds (``raster`` draws of each inclusion) expected to lie unsensed at ``ratio``, at the least."""
    return sum(int(r["raster"]) * hide_probability(float(r["radius_mm"]), reach_mm, ratio, spacing_mm, sweep_mm)
               for r in rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="an output directory of bench/adaptive.py (its inclusion_rates.csv)")
    ap.add_argument("--reach-mm", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.1, 0.15, 0.2])
    ap.add_argument("--spacing-mm", type=float, default=3.0, help="the raster's line spacing")
    ap.add_argument("--sweep-mm", type=float, default=6.0, help="one probe's sweep (the planner's length_mm)")
    args = ap.parse_args()
    rows = list(csv.DictReader((args.out / "inclusion_rates.csv").open(encoding="utf-8")))
    found = sum(int(r["raster"]) for r in rows)
    out: dict[str, float] = {}
    print(f"{args.out}: {len(rows)} inclusions, {found} found by the raster over the draws")
    for reach in args.reach_mm:
        for ratio in args.ratios:
            n = expected_unsensed(rows, reach, ratio, args.spacing_mm, args.sweep_mm)
            out[f"unsensed_reach{reach:g}_ratio{ratio:g}"] = round(n, 1)
            print(f"  reach {reach:g} mm, probe ratio {ratio:g}: {n:.1f} of the raster's {found} finds unsensed in "
                  "expectation, at the least")
    print(json.dumps({"raster_found": found, **out}))


if __name__ == "__main__":
    main()
