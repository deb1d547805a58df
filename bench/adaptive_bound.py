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

A second bound, from detection (``--snr``): the information a scheme spends. An inclusion the raster found at
significance ``s`` (its ``inclusions.json``) gives, from a fraction ``q`` of the raster's samples over its disc, about
``q s^2`` of the raster's information (white noise, the signal spread evenly over the disc). Any sequential test at
one place that dismisses a blank place with probability 1 - b and spends ``t`` there on average when it is blank
misses an inclusion there with probability ``a`` at least where ``d(1 - b, a) <= t s^2 / 2`` (d: the binary
Kullback-Leibler divergence; Wald, Hoeffding). The inclusion's place is not known before, so spread over the
region a planner at ratio ``f`` spends ``f`` on average, and by convexity it misses the inclusion with probability
at least ``a(f)``. Summed over the raster's finds, that is the misses in expectation of the best conceivable planner
at ``f`` (b = 0: every blank place dismissed; b = 0.1: a tenth of them kept for a closer look, paid on top). It is
rough (a sparse look at correlated noise, or at a peaked signal, is worth more than its share), and optimistic for
the planner in all else (no travel, any granularity, a background known exactly).

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


def least_miss(snr: float, ratio: float, keep: float) -> float:
    """The smallest probability ``a`` of dismissing an inclusion of raster significance ``snr`` that a sequential
    test spending ``ratio`` of the raster's information where nothing is, and keeping a blank place with probability
    ``keep``, can have: the root of ``d(1 - keep, a) = ratio snr^2 / 2`` below ``1 - keep`` (module doc)."""
    budget = ratio * snr * snr / 2.0
    p = 1.0 - keep

    def kl(log_a: float) -> float:   # d(p, a) in terms of ln a (a underflows for strong inclusions)
        return p * (math.log(p) - log_a) + (keep * math.log(keep / -math.expm1(log_a)) if keep > 0 else 0.0)

    lo, hi = -budget / p - 50.0, math.log(p)   # kl(lo) > budget >= kl(hi) = 0; kl falls as a rises
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if kl(mid) <= budget else (mid, hi)
    return math.exp(hi)


def raster_snrs(out: Path) -> list[float]:
    """The significance of every inclusion the raster's maps report (``OUT/raster/runs/*/map/inclusions.json``)."""
    snrs = []
    for f in sorted((out / "raster" / "runs").glob("*/map/inclusions.json")):
        doc = json.loads(f.read_text(encoding="utf-8"))
        snrs += [float(i["snr"]) for i in (doc["inclusions"] if isinstance(doc, dict) else doc) if "snr" in i]
    return snrs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="an output directory of bench/adaptive.py (its inclusion_rates.csv)")
    ap.add_argument("--reach-mm", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.1, 0.15, 0.2])
    ap.add_argument("--spacing-mm", type=float, default=3.0, help="the raster's line spacing")
    ap.add_argument("--snr", action="store_true", help="also the detection bound (module doc; the raster's maps)")
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
    if args.snr:
        snrs = raster_snrs(args.out)
        print(f"detection bound: {len(snrs)} raster detections, significance {min(snrs):.1f}-{max(snrs):.1f}")
        for keep in (0.0, 0.1):
            for ratio in args.ratios:
                n = sum(least_miss(x, ratio, keep) for x in snrs)
                out[f"misses_keep{keep:g}_ratio{ratio:g}"] = round(n, 2)
                print(f"  probe ratio {ratio:g}, blank places kept {keep:g}: {n:.2f} of them missed in expectation, "
                      "at the least")
    print(json.dumps({"raster_found": found, **out}))


if __name__ == "__main__":
    main()
