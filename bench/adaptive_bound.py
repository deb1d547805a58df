"""How many of the raster's finds any planner must leave unsensed at a given probe ratio: a bound from geometry alone.

    .venv/bin/python bench/adaptive_bound.py runs/bench_adaptive            # an output of bench/adaptive.py
    .venv/bin/python bench/adaptive_bound.py OUT --reach-mm 2.0 --ratios 0.2 0.25 0.3

A sweep senses an inclusion of radius ``r`` only if it passes within ``r + reach`` of its centre (the excess
stiffness reaches ``reach`` past the edge: median 2 mm, a quarter of them 1 mm or less, bench/airfloat_reach.py; the
planner's own model takes 1.5 mm). A planner whose sweeps add up to a fraction ``f`` of the raster's swept length
(``probe_ratio``, bench/adaptive.py) covers the most area with parallel sweeps ``spacing / f`` apart (``spacing``:
the raster's, 3 mm): no arrangement of that length senses more, since each millimetre of sweep senses a band
``2 (r + reach)`` wide at most. An inclusion whose centre is uniform over the region then hides between two such
sweeps with probability ``max(0, 1 - 2 (r + reach) f / spacing)``, before the planner has spent a single probe on
confirming anything, and whatever it decides, since it decides on what it has sensed.

Summed over the inclusion-draws the raster found (``inclusion_rates.csv``: each true inclusion's radius and the
number of draws the raster found it in), that is the number of the raster's finds a planner at ratio ``f`` misses
in expectation, at the least: compare it with ``raster_redraw_missed``, what a second raster would miss. The last
line is JSON.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path


def hide_probability(radius_mm: float, reach_mm: float, ratio: float, spacing_mm: float) -> float:
    """Probability that an inclusion of ``radius_mm``, its centre uniform, lies farther than its radius plus
    ``reach_mm`` from every one of parallel sweeps ``spacing_mm / ratio`` apart."""
    gap = spacing_mm / ratio
    return max(0.0, 1.0 - 2.0 * (radius_mm + reach_mm) / gap)


def expected_unsensed(rows: list[dict[str, str]], reach_mm: float, ratio: float, spacing_mm: float) -> float:
    """The raster's finds (``raster`` draws of each inclusion) expected to lie unsensed at ``ratio``."""
    return sum(int(r["raster"]) * hide_probability(float(r["radius_mm"]), reach_mm, ratio, spacing_mm)
               for r in rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="an output directory of bench/adaptive.py (its inclusion_rates.csv)")
    ap.add_argument("--reach-mm", type=float, nargs="+", default=[1.5, 2.0])
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.15, 0.2, 0.25, 0.3])
    ap.add_argument("--spacing-mm", type=float, default=3.0, help="the raster's line spacing")
    args = ap.parse_args()
    rows = list(csv.DictReader((args.out / "inclusion_rates.csv").open(encoding="utf-8")))
    found = sum(int(r["raster"]) for r in rows)
    out: dict[str, float] = {}
    print(f"{args.out}: {len(rows)} inclusions, {found} found by the raster over the draws")
    for reach in args.reach_mm:
        for ratio in args.ratios:
            n = expected_unsensed(rows, reach, ratio, args.spacing_mm)
            out[f"unsensed_reach{reach:g}_ratio{ratio:g}"] = round(n, 1)
            print(f"  reach {reach:g} mm, probe ratio {ratio:g} (sweeps {args.spacing_mm / ratio:.1f} mm apart): "
                  f"{n:.1f} of the raster's {found} finds unsensed in expectation, at the least")
    print(json.dumps({"raster_found": found, **out}))


if __name__ == "__main__":
    main()
