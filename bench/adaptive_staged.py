"""Can a staged scheme (sense sparsely, then confirm where it is suspicious) find what the raster finds at a fifth of
its probes? A study on the raster's own maps, travel ignored (issue 41).

    .venv/bin/python bench/adaptive_staged.py runs/fresh14500        # an output of bench/adaptive.py (its raster runs)

Every raster run of OUT (``OUT/raster/runs/*/map/map.npz``) is the measurement pool: a scheme *reveals* cells of it,
and a revealed cell keeps the raster's value and sample count; the rest are blind. The revealed map is presented to
the detector as the adaptive planner presents its own (models.adaptive_detect.detect_candidates, its final
detection and what bench/adaptive.py scores): the measured cells, the GP mean (models.adaptive.fit_belief, its
kernel fitted on the lattice's cells) within ``fill_mm`` of one, NaN farther; background and noise from the
stiffness-blind cells (here the stage-1 lattice's); a detection with two measured maxima split. ``--nan`` presents
blind cells as NaN instead, as the raster's map has its gaps between lines (models.detector.detect with the map's
law, as nodes.mapping.map_output.redetect; background and noise from the lattice's cells too): revealing every cell,
every one fair, then gives the raster's own detections exactly. The frontier's schemes are scored both ways.

A scheme: (1) a stage-1 lattice, stiffness-blind: every ``k``-th raster line, whole or in 6 mm segments (3 cells)
every ``P`` cells, staggered by half a period from one chosen line to the next; (2) on the revealed map, the
detector's own matched-filter significance (the largest over its disc radii, ``Detection.significance``); every
raster cell within ``R`` of a cell above ``t1`` is revealed (``skip found``: not around a cell inside a current
detection's disc + ``R``, whose halo would cost the most and confirm nothing); (3) stages 2.. do the same on the new
map with ``t1 + (stage - 1) dt`` (distilled sensing: each stage confirms what is still above its bar); (4) the
detector's final detections on the last map. Scored per run against the raster's own finds on that run (its
``inclusions.json`` through models.scoring.score_scan, tools.evaluate's scorer): ``missed`` = the raster's finds
the scheme's map does not find; false positives as score_scan counts them against the phantom's truth. The frontier
is given twice: the fewest misses whatever the false positives, and with at most FP_PER_RUN of them a map.

Probe cost = the swept length of the revealed cells over the raster's, pooled over the runs (bench/adaptive.py's
``probe_ratio`` is swept length in contact): a cell stands for the 2 mm of line that crossed it, its samples over a
full cell's (the median measured cell's), at most one (:func:`lengths`; by raw samples the first and last rows
would cost a third of the map: the probe dwells at every line's turnaround). Revealing single cells is the cheapest
any sweep could: a 6 mm sweep reveals three. So the figures bound what a planner placing its sweeps by this rule
could do, travel and sweep granularity only making it worse; and the parameters are chosen on the runs they are
scored on (optimistic). The ``half-chosen`` figures choose on one half of the phantoms (every other one, by name)
and score on the other, both ways, summed. The ``oracle`` rows reveal a lattice and every cell within a true
inclusion's radius + 2 mm (``lost``: only of the raster's finds the lattice's own map misses): confirmation's cost
with perfect knowledge of where to look; they also say how many of the lattice's own false positives are fragments of
a true inclusion (:func:`fp_split`). ``raster_redraw_missed`` (models.scoring.redraw_misses) is the yardstick. The
last line is JSON.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from models.adaptive import PlannerConfig, fit_belief  # noqa: E402
from models.adaptive_cover import distance_to_measured  # noqa: E402
from models.adaptive_detect import detect_candidates  # noqa: E402
from models.detector import Detection, DetectorConfig, detect, with_law_of  # noqa: E402
from models.phantom import Phantom, load_phantom  # noqa: E402
from models.scoring import redraw_misses, score_scan  # noqa: E402
from models.stiffness_map import MapSnapshot, fill_gaps, to_inclusions_json  # noqa: E402
from nodes.mapping.map_output import map_model, read_map  # noqa: E402
from yamlstruct import Source  # noqa: E402

BoolArray = npt.NDArray[np.bool_]
SEGMENT_CELLS = 3
"""A 6 mm sweep on the 2 mm grid (the planner's length_mm)."""
LATTICES = ((4, 0), (6, 0), (8, 0), (2, 6), (2, 9), (2, 12), (3, 6), (3, 9), (3, 12), (4, 9))
"""(k, P): every k-th raster line, whole (P = 0) or a 3-cell segment every P cells: 0.10-0.28 of its length."""
THRESHOLDS = (2.0, 2.5, 3.0, 3.5)
RADII_MM = (2.0, 4.0)
STEPS = (0.0, 1.0)
BUDGETS = (0.10, 0.15, 0.20, 0.25, 0.30)
ORACLE_HALO_MM = 2.0
FRAGMENT_MM = 4.0
"""A false positive centred within a true inclusion's radius + this is a fragment of it (:func:`fp_split`)."""
FP_PER_RUN = 0.1
"""The second frontier's cap on false positives: one map in ten (the planner's 5 on the 63 maps of set 14500); the
raster's maps show none, and a scheme spraying detections finds some inclusions by chance."""


class Scheme(NamedTuple):
    """Stage-1 lattice (k, P), then ``stages`` rounds revealing within ``radius_mm`` of significance above
    ``t1 + (stage - 1) * step`` (stages 0: the lattice alone)."""

    k: int
    period: int
    t1: float = math.inf
    radius_mm: float = 0.0
    stages: int = 0
    step: float = 0.0
    skip_found: bool = False
    """Cells within a detection's disc + ``radius_mm`` are not confirmed again (a strong inclusion's halo is large)."""

    def label(self) -> str:
        lat = f"k{self.k}" + (f"/P{self.period}" if self.period else " lines")
        if not self.stages:
            return lat
        return (f"{lat}, t1 {self.t1:g}, R {self.radius_mm:g}, {self.stages} st, dt {self.step:g}"
                + (", skip found" if self.skip_found else ""))


class Run(NamedTuple):
    """One raster run: its map, the phantom's truth, which true inclusions the raster found."""

    id: str
    phantom_id: str
    phantom: Phantom
    snap: MapSnapshot
    model: str
    raster_found: tuple[bool, ...]
    kernels: dict[tuple[int, int], object]
    """The GP kernel fitted on each lattice's cells, kept for the later stages' maps (posterior only)."""


def lattice(snap: MapSnapshot, k: int, period: int) -> BoolArray:
    """The stage-1 cells (module doc): of the raster's lines (cell columns holding at least half the fullest
    column's samples), every k-th, whole or one 3-cell segment every ``period`` cells, staggered."""
    count = np.asarray(snap.count)
    per_col = count.sum(axis=0)
    lines = np.flatnonzero(per_col >= 0.5 * per_col.max())
    rows = np.arange(count.shape[0])
    out = np.zeros(count.shape, dtype=bool)
    for j, col in enumerate(lines[::k]):
        out[:, col] = True if not period else (rows - (j % 2) * (period // 2)) % period < SEGMENT_CELLS
    return out & np.isfinite(snap.stiffness)


def lengths(snap: MapSnapshot) -> npt.NDArray[np.float64]:
    """Per cell, the raster line's length it stands for in cells: its samples over the median measured cell's, at
    most one (0 where unmeasured)."""
    count = np.where(np.isfinite(snap.stiffness), np.asarray(snap.count, dtype=np.float64), 0.0)
    full = float(np.median(count[count > 0])) if (count > 0).any() else 1.0
    return np.asarray(np.minimum(count / full, 1.0), dtype=np.float64)


def grow(revealed: BoolArray, hot: BoolArray, available: BoolArray, radius_mm: float, cell_mm: float) -> BoolArray:
    """``revealed`` and every ``available`` cell within ``radius_mm`` of a ``hot`` one."""
    near = distance_to_measured(hot, cell_mm) <= radius_mm + 1e-9
    return np.asarray(revealed | (near & available), dtype=bool)


def detect_revealed(run: Run, revealed: BoolArray, fair: BoolArray | None, *, nan: bool = False,
                    kernel: object = None) -> tuple[Detection, object]:
    """The detector on the map of the ``revealed`` cells (module doc), and the GP kernel used (fitted on the
    revealed cells when ``kernel`` is None). ``fair``: the stiffness-blind cells, the background's and noise's
    (None: every valid cell, as the raster's map); ``nan``: blind cells NaN, no GP (the raster map's presentation)."""
    s = run.snap
    grid = np.where(revealed, s.stiffness, np.nan)
    counts = np.where(revealed, s.count, 0)
    if nan:
        part = MapSnapshot(grid, s.x_mm, s.y_mm, counts, np.where(revealed, s.spread, np.nan), s.resolution_mm)
        blind = np.isfinite(fill_gaps(s.stiffness)) & ~revealed   # tissue on the raster's map, unmeasured here
        return detect(part, with_law_of(DetectorConfig(), run.model), estimate_from=fair, unmeasured=blind), kernel
    cfg = planner_config(s, run.model)
    gx, gy = np.meshgrid(s.x_mm, s.y_mm)
    belief = fit_belief(list(zip(gx[revealed], gy[revealed], strict=True)), grid[revealed].tolist(), cfg,
                        kernel=kernel)
    _, det = detect_candidates(belief, grid, counts, cfg, None if fair is None else np.where(fair, s.stiffness, np.nan))
    return det, belief.kernel


def planner_config(snap: MapSnapshot, model: str) -> PlannerConfig:
    """The planner's settings (launch/scan_adaptive_sim.yaml's defaults) over the raster map's cells."""
    h = 0.5 * snap.resolution_mm
    region = (float(snap.x_mm[0]) - h, float(snap.y_mm[0]) - h, float(snap.x_mm[-1]) + h, float(snap.y_mm[-1]) + h)
    return PlannerConfig(region, resolution_mm=snap.resolution_mm, model=model, length_scale_mm=(1.0, 3.0),
                         sweep_mm=6.0)


def score(run: Run, det: Detection) -> tuple[tuple[bool, ...], int]:
    """Which true inclusions ``det`` finds and how many false positives (models.scoring.score_scan)."""
    s = run.snap
    sc = score_scan(run.phantom, to_inclusions_json(det.inclusions),
                    {"stiffness": s.stiffness, "x_mm": s.x_mm, "y_mm": s.y_mm, "count": s.count})
    return tuple(x.found for x in sc.inclusions), len(sc.false_positives)


def fp_split(run: Run, det: Detection) -> tuple[int, int]:
    """``det``'s false positives (models.scoring.score_scan) as (fragments, far): centred within FRAGMENT_MM of a
    true inclusion's disc, or farther. On a partial map an inclusion crossed by two lattice segments with blind
    cells between them is two regions, one of them matched and the other false; only the far ones are the map's
    noise, what a false-alarm law speaks of."""
    s = run.snap
    sc = score_scan(run.phantom, to_inclusions_json(det.inclusions),
                    {"stiffness": s.stiffness, "x_mm": s.x_mm, "y_mm": s.y_mm, "count": s.count})
    near = sum(any(math.hypot(f.x_mm - i.center_mm[0], f.y_mm - i.center_mm[1]) < i.radius_mm + FRAGMENT_MM
                   for i in run.phantom.inclusions) for f in sc.false_positives)
    return near, len(sc.false_positives) - near


Outcome = tuple[float, tuple[bool, ...], int]
"""(revealed length in cells, true inclusions found, false positives)."""


def run_scheme(run: Run, scheme: Scheme, *, nan: bool = False,
               cache: dict[bytes, tuple[Detection, object]] | None = None) -> Outcome:
    """One scheme on one run (module doc). ``cache``: detections by revealed mask, for one run and lattice."""
    s = run.snap
    available = np.isfinite(s.stiffness)
    fair = lattice(s, scheme.k, scheme.period)
    key = (scheme.k, scheme.period)
    cache = {} if cache is None else cache

    def detected(mask: BoolArray) -> Detection:
        tag = mask.tobytes()
        if tag not in cache:
            kernel = run.kernels.get(key)
            cache[tag] = detect_revealed(run, mask, fair, nan=nan, kernel=kernel)
            if not nan:
                run.kernels.setdefault(key, cache[tag][1])   # fitted on the lattice, kept for the later stages
        return cache[tag][0]

    gx, gy = np.meshgrid(s.x_mm, s.y_mm)
    revealed = fair
    det = detected(revealed)
    for stage in range(scheme.stages):
        hot = np.nan_to_num(det.significance, nan=-np.inf) > scheme.t1 + stage * scheme.step
        if scheme.skip_found:
            for inc in det.inclusions:
                hot &= np.hypot(gx - inc.x_mm, gy - inc.y_mm) > inc.radius_mm + scheme.radius_mm
        more = grow(revealed, hot, available, scheme.radius_mm, s.resolution_mm)
        if np.array_equal(more, revealed):
            break
        revealed = more
        det = detected(revealed)
    found, fp = score(run, det)
    return float(lengths(s)[revealed].sum()), found, fp


def oracle(run: Run, k: int, period: int, *, nan: bool = False, lost_only: bool = False) -> Outcome:
    """The lattice and every cell within a true inclusion's radius + ORACLE_HALO_MM of its centre (``lost_only``:
    only of those the raster finds and the lattice's map does not)."""
    s = run.snap
    gx, gy = np.meshgrid(s.x_mm, s.y_mm)
    fair = lattice(s, k, period)
    near = np.zeros(fair.shape, dtype=bool)
    seen = score(run, detect_revealed(run, fair, fair, nan=nan, kernel=run.kernels.get((k, period)))[0])[0]
    for inc, r, a in zip(run.phantom.inclusions, run.raster_found, seen, strict=True):
        if lost_only and (a or not r):
            continue
        cx, cy = inc.center_mm
        near |= np.hypot(gx - cx, gy - cy) <= inc.radius_mm + ORACLE_HALO_MM
    revealed = fair | (near & np.isfinite(s.stiffness))
    det, _ = detect_revealed(run, revealed, fair, nan=nan, kernel=run.kernels.get((k, period)))
    found, fp = score(run, det)
    return float(lengths(s)[revealed].sum()), found, fp


def reveal_all(run: Run, *, nan: bool = False) -> Outcome:
    """Every raster cell revealed, every one fair: with ``nan``, the raster map's own detection."""
    every = np.isfinite(run.snap.stiffness)
    det, _ = detect_revealed(run, every, None, nan=nan)
    found, fp = score(run, det)
    return float(lengths(run.snap)[every].sum()), found, fp


def load_runs(out: Path) -> list[Run]:
    """The raster runs of a bench/adaptive.py output, by id; the raster's finds from its ``inclusions.json``."""
    runs = []
    for npz in sorted((out / "raster" / "runs").glob("*/map/map.npz")):
        rd = npz.parent.parent
        if rd.is_symlink() or rd.name.endswith("-again"):   # latest -> the last run
            continue
        resolved = Source.read(rd / "launch.resolved.yaml").data
        path = next(a["default"] for a in resolved["args"] if a["name"] == "phantom")
        ph = load_phantom(Path(path))
        snap = read_map(npz)
        dets = json.loads((npz.parent / "inclusions.json").read_text())
        sc = score_scan(ph, dets, dict(np.load(npz)))
        runs.append(Run(rd.name, Path(path).stem, ph, snap, map_model(npz), tuple(x.found for x in sc.inclusions), {}))
    return runs


def schemes() -> list[Scheme]:
    """The grid (module doc): the lattices alone, then every (t1, R, skip_found) for one stage and with dt for two
    and three."""
    out = [Scheme(k, p) for k, p in LATTICES]
    for (k, p), t1, r, skip in itertools.product(LATTICES, THRESHOLDS, RADII_MM, (False, True)):
        out.append(Scheme(k, p, t1, r, 1, 0.0, skip))
        out += [Scheme(k, p, t1, r, n, dt, skip) for n in (2, 3) for dt in STEPS]
    return out


def tally(runs: list[Run], outcomes: Iterable[Outcome]) -> dict[str, Any]:
    """Pooled probe ratio, missed (raster finds not found), found beyond the raster, false positives."""
    cost = total = 0.0
    missed = extra = fp = 0
    for run, (c, found, f) in zip(runs, outcomes, strict=True):
        cost += c
        total += float(lengths(run.snap).sum())
        missed += sum(r and not a for r, a in zip(run.raster_found, found, strict=True))
        extra += sum(a and not r for r, a in zip(run.raster_found, found, strict=True))
        fp += f
    return {"probe_ratio": round(cost / total, 4) if total else math.nan, "missed": missed, "extra": extra, "fp": fp,
            "cost": cost, "samples": total}


def public(t: dict[str, Any]) -> dict[str, Any]:
    """A tally without its raw sums."""
    return {k: v for k, v in t.items() if k not in ("cost", "samples")}


def redraw(runs: list[Run]) -> float:
    """The raster's own redraw misses over these runs (models.scoring.redraw_misses, the draws each phantom has)."""
    by: dict[str, list[tuple[bool, ...]]] = {}
    for r in runs:
        by.setdefault(r.phantom_id, []).append(r.raster_found)
    return sum(redraw_misses([sum(col) for col in zip(*v, strict=True)], len(v)) for v in by.values() if len(v) > 1)


def best(table: dict[Scheme, dict[str, Any]], budget: float, max_fp: float = math.inf) -> Scheme | None:
    """The scheme within ``budget`` (and ``max_fp`` false positives) with the fewest misses, then false positives,
    then probes."""
    ok = [s for s, t in table.items() if t["probe_ratio"] <= budget + 1e-9 and t["fp"] <= max_fp]
    return min(ok, key=lambda s: (table[s]["missed"], table[s]["fp"], table[s]["probe_ratio"]), default=None)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="an output directory of bench/adaptive.py (its raster runs)")
    ap.add_argument("--nan", action="store_true", help="grid-search with blind cells NaN (the raster map's own "
                    "presentation) instead of the planner's")
    ap.add_argument("--no-other", action="store_true", help="do not score the frontier's schemes again with the other "
                    "presentation (the planner's takes minutes a set)")
    ap.add_argument("--runs", type=int, default=0, help="only every N-th run (a quick look; 0: all)")
    opts = ap.parse_args(argv)
    t0 = time.monotonic()
    runs = load_runs(opts.out)
    runs = runs[:: opts.runs] if opts.runs else runs
    found = sum(sum(r.raster_found) for r in runs)
    print(f"{opts.out}: {len(runs)} raster runs, {found} raster finds, raster redraw missed {redraw(runs):.1f}")
    grid = schemes()
    per_run: dict[Scheme, list[Outcome]] = {s: [] for s in grid}
    for run in runs:
        caches: dict[tuple[int, int], dict[bytes, tuple[Detection, object]]] = {}
        for s in grid:
            per_run[s].append(run_scheme(run, s, nan=opts.nan, cache=caches.setdefault((s.k, s.period), {})))
    table = {s: tally(runs, per_run[s]) for s in grid}
    everything = tally(runs, (reveal_all(r, nan=opts.nan) for r in runs))
    print(f"reveal every raster cell: missed {everything['missed']}, beyond the raster {everything['extra']}, "
          f"fp {everything['fp']} ({'NaN' if opts.nan else 'planner'} presentation)")
    halves = sorted({r.phantom_id for r in runs})
    split = [{p for i, p in enumerate(halves) if i % 2 == h} for h in (0, 1)]
    idx = [[i for i, r in enumerate(runs) if r.phantom_id in half] for half in split]

    def part(s: Scheme, h: int) -> dict[str, Any]:
        return tally([runs[i] for i in idx[h]], [per_run[s][i] for i in idx[h]])

    halftables = [{x: part(x, h) for x in grid} for h in (0, 1)]
    other = "planner's" if opts.nan else "NaN"
    frontier = []
    for cap in (math.inf, FP_PER_RUN):
        print(f"fewest misses within each budget{'' if cap == math.inf else f', fp <= {cap:g} a run'}; "
              f"scored again with the {other} presentation; chosen on one half of the phantoms, scored on the other")
        print(f"| budget | scheme | probe ratio | missed | fp | missed, fp ({other}) | half-chosen: probe ratio, "
              "missed, fp |")
        print("|---|---|---|---|---|---|---|")
        for b in BUDGETS:
            pick = best(table, b, cap * len(runs))
            if pick is None:
                print(f"| {b:.2f} | none | | | | | |")
                continue
            s = pick
            t = table[s]
            alt = ({"missed": "-", "fp": "-"} if opts.no_other
                   else tally(runs, (run_scheme(r, s, nan=not opts.nan) for r in runs)))
            # two-fold: choose on one half's table, score on the other half, both ways
            held = [part(c, 1 - h) for h, c in enumerate(best(halftables[h], b, cap * len(idx[h])) for h in (0, 1))
                    if c is not None]
            pooled = sum(x["cost"] for x in held) / sum(x["samples"] for x in held) if held else math.nan
            hm, hf = sum(x["missed"] for x in held), sum(x["fp"] for x in held)
            print(f"| {b:.2f} | {s.label()} | {t['probe_ratio']:.3f} | {t['missed']} | {t['fp']} | {alt['missed']}, "
                  f"{alt['fp']} | {pooled:.3f}, {hm}, {hf} |")
            frontier.append({"budget": b, "max_fp_per_run": None if cap == math.inf else cap,
                             "scheme": s.label(), **public(t), "other_presentation": public(alt),
                             "half_probe_ratio": round(pooled, 4), "half_missed": hm, "half_fp": hf})
    print("oracle (the lattice and every raster cell within a true inclusion's r + 2 mm; 'lost': only of those the "
          "raster finds and the lattice's map does not):")
    oracles = []
    for k, p in LATTICES:
        lat = table[Scheme(k, p)]
        every, lost = (tally(runs, (oracle(r, k, p, nan=opts.nan, lost_only=x) for r in runs)) for x in (False, True))
        near = sum(fp_split(r, detect_revealed(r, lattice(r.snap, k, p), lattice(r.snap, k, p), nan=opts.nan,
                                               kernel=r.kernels.get((k, p)))[0])[0] for r in runs)
        print(f"  {Scheme(k, p).label():10s} lattice alone {lat['probe_ratio']:.3f} (missed {lat['missed']}, fp "
              f"{lat['fp']}, {near} of them fragments); oracle {every['probe_ratio']:.3f}: missed {every['missed']}, "
              f"fp {every['fp']}; lost {lost['probe_ratio']:.3f}: missed {lost['missed']}, fp {lost['fp']}")
        oracles.append({"lattice": Scheme(k, p).label(), "lattice_ratio": lat["probe_ratio"],
                        "lattice_missed": lat["missed"], "lattice_fp": lat["fp"], "lattice_fp_fragments": near,
                        "all": public(every), "lost": public(lost)})
    print(f"{len(grid)} schemes x {len(runs)} runs in {time.monotonic() - t0:.0f} s")
    print(json.dumps({"runs": len(runs), "raster_found": found, "raster_redraw_missed": round(redraw(runs), 1),
                      "presentation": "nan" if opts.nan else "planner", "reveal_all": public(everything),
                      "frontier": frontier, "oracle": oracles}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
