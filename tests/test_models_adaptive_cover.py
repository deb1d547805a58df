"""models.adaptive_cover: the staggered lattice of covering sweeps, the seed snapped onto it, and decide() taking it
before the greedy cover."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from models.adaptive import Belief, PlannerConfig, probe_points
from models.adaptive_cover import (
    cover_cost,
    cover_lattice,
    distance_to_measured,
    lattice_cells,
    miss_probability,
    seed_design,
    valid_rows,
)
from models.adaptive_detect import decide

REGION = (6.0, 6.0, 52.0, 50.0)   # 23 x 22 cells of 2 mm: the size of a generated phantom's region


def _cfg(**kw: Any) -> PlannerConfig:
    # the lattice of 8 mm columns and a 14 mm period at a 2 % miss probability (the defaults are 12 mm and 1 %)
    kw = {"miss_probability": 0.02, "cover_period_mm": 14.0, **kw}
    return PlannerConfig(kw.pop("region", REGION), sweep_mm=6.0, seed_spacing_mm=14.0, **kw)


def _flat_run(cfg: PlannerConfig) -> tuple[list[tuple[float, float]], npt.NDArray[np.bool_], list[str]]:
    """decide() on tissue with nothing in it, every sweep measuring the cells it crosses, until it stops: the
    covering alone (its probes, the cells they measured, and what decide() said each was for after the seed)."""
    xs, ys = cfg.grid()
    gx, gy = np.meshgrid(xs, ys)
    measured = np.full(gx.shape, np.nan)
    belief = Belief(xs, ys, np.full(gx.shape, 10.0), np.full(gx.shape, 0.5), 10.0, 12.0)
    probed: list[tuple[float, float]] = []
    kinds: list[str] = []

    def sweep(p: tuple[float, float]) -> None:
        measured[(np.abs(gx - p[0]) <= 1.0) & (np.abs(gy - p[1]) <= 3.0)] = 10.0
        probed.append(p)

    for p in seed_design(cfg):
        sweep(p)
    while True:
        d = decide(belief, measured, np.isfinite(measured).astype(np.int64), probed, cfg, probed[-1], measured)
        if d.stop:
            assert d.why.startswith("found")
            return probed, np.isfinite(measured), kinds
        assert d.point is not None and d.blind
        kinds.append(d.kind)
        sweep(d.point)


def test_lattice_columns_and_rows_are_staggered_half_a_period() -> None:
    cells = lattice_cells((30, 12), 3, 4, 7, 1, 2)
    columns = sorted({ix for _, ix in cells})
    assert columns == [1, 5, 9]
    rows = {ix: sorted(iy for iy, jx in cells if jx == ix) for ix in columns}
    assert rows[1] == [2, 9, 16, 23, 28]      # every 7 rows from row 2; 30 still crosses row 29: moved in to 28
    assert rows[5] == [5, 12, 19, 26]         # half a period (3) along; -2 would cross rows -3..-1: none
    assert rows[9] == rows[1]
    # serpentine: up the first column, down the next
    assert [iy for iy, ix in cells if ix == 5] == rows[5][::-1]
    first, last = valid_rows(30, 3)
    assert all(first <= iy <= last for iy, _ in cells) and (first, last) == (1, 28)


def test_a_sweep_past_the_edge_is_moved_in_only_when_it_still_crosses_the_grid() -> None:
    # period 10 from row 9: centres -1 (crosses row 0), 9, 19 (crosses row 20 only if ny > 18)
    assert [iy for iy, _ in lattice_cells((19, 1), 3, 4, 10, 0, 9)] == [1, 9, 17]
    assert [iy for iy, _ in lattice_cells((17, 1), 3, 4, 10, 0, 9)] == [1, 9]   # 19 - 1 = 18 > 16: off the grid
    assert lattice_cells((2, 5), 3, 4, 7, 0, 0) == []   # no row a 3-cell sweep fits in
    assert lattice_cells((5, 1), 3, 4, 1, 0, 0) == [(1, 0), (2, 0), (3, 0)]   # sweeps moved in are not repeated


def test_the_lattice_covers_with_fewer_sweeps_than_the_greedy_cover_for_the_same_guarantee() -> None:
    big = (6.0, 6.0, 60.0, 56.0)   # 27 x 25 cells, a large generated phantom's region
    lattice, greedy = _cfg(region=big), _cfg(region=big, cover_column_mm=0.0)
    a, measured_a, _ = _flat_run(lattice)
    b, measured_b, _ = _flat_run(greedy)
    for cfg, measured in ((lattice, measured_a), (greedy, measured_b)):
        assert miss_probability(measured, 2.0, cfg.reaches()) < cfg.miss_probability
    # the greedy cover needs 36 sweeps, the brick lattice 28
    assert len(a) <= 28 < 34 <= len(b)
    # and at the defaults (2 %, a 14 mm period): 28 against 36
    c, _, _ = _flat_run(PlannerConfig(big, sweep_mm=6.0, seed_spacing_mm=14.0))
    d, _, _ = _flat_run(PlannerConfig(big, sweep_mm=6.0, seed_spacing_mm=14.0, cover_column_mm=0.0))
    assert len(c) <= 28 < 34 <= len(d)
    # the covering is a brick wall: 1 % of the cells (corners) lie farther than 4.5 mm from a measured one, none
    # farther than 6 mm (the greedy cover's leaves 2 %, up to 6.3 mm: it is not the lattice that leaves more room)
    dist = distance_to_measured(measured_a, 2.0)
    assert np.count_nonzero(dist > 4.5) <= 0.01 * dist.size and float(dist.max()) < 6.0


def test_the_lattice_is_deterministic_and_its_phase_the_cheapest_for_the_region() -> None:
    cfg = _cfg(region=(6.0, 6.0, 46.0, 44.0))   # 20 x 19 cells: the cheapest phase starts neither row nor column 0
    cells = cover_lattice(cfg)
    assert cells == cover_lattice(PlannerConfig((6.0, 6.0, 46.0, 44.0), sweep_mm=6.0, seed_spacing_mm=14.0,
                                                miss_probability=0.02, cover_period_mm=14.0))
    xs, ys = cfg.grid()
    shape = (len(ys), len(xs))
    costs = {(c0, r0): cover_cost(cfg, lattice_cells(shape, 3, 4, 7, c0, r0)) for c0 in range(4) for r0 in range(7)}
    assert cover_cost(cfg, cells) == min(costs.values()) == 17
    assert cells == tuple(lattice_cells(shape, 3, 4, 7, *min(costs, key=lambda k: (costs[k], k))))
    # the phase matters here: with the first row, or the first column, every lattice costs one sweep more
    assert min(costs[c0, 0] for c0 in range(4)) == min(costs[0, r0] for r0 in range(7)) == 18
    # the cost counts the greedy sweeps that patch the lattice's edges: none needed for a lattice over every cell
    every = [(iy, ix) for ix in range(shape[1]) for iy in range(1, shape[0] - 1, 3)]
    assert cover_cost(cfg, every, limit=1000) == len(every) and 0 < cover_cost(cfg, []) < 60
    assert cover_cost(cfg, [], limit=3) == 3


def test_the_lattice_is_off_without_sweeps() -> None:
    assert cover_lattice(_cfg(cover_column_mm=0.0)) == ()
    assert cover_lattice(PlannerConfig(REGION, sweep_mm=0.0)) == ()   # presses: no lattice


def test_the_seed_grid_is_snapped_onto_the_lattice() -> None:
    cfg = _cfg()
    px, py = probe_points(None, cfg)
    on_lattice = {(float(px[iy, ix]), float(py[iy, ix])) for iy, ix in cover_lattice(cfg)}
    seeds = seed_design(cfg)
    assert 6 <= len(seeds) <= 9 and len(set(seeds)) == len(seeds)
    assert set(seeds) <= on_lattice
    off = seed_design(_cfg(cover_column_mm=0.0))
    assert len(off) == 9 and not set(off) <= on_lattice   # without the lattice: the 14 mm seed grid itself


def test_decide_takes_lattice_sweeps_while_one_reveals_something_then_the_greedy_one() -> None:
    cfg = _cfg()
    probed, _, kinds = _flat_run(cfg)
    px, py = probe_points(None, cfg)
    on_lattice = {(float(px[iy, ix]), float(py[iy, ix])) for iy, ix in cover_lattice(cfg)}
    after_seed = probed[len(seed_design(cfg)):]
    # lattice sweeps first, then (at most) a few greedy ones patching what it left at the edges
    n = sum(p in on_lattice for p in after_seed)
    assert n >= 5 and [p in on_lattice for p in after_seed] == [True] * n + [False] * (len(after_seed) - n)
    assert len(after_seed) - n <= 2
    assert kinds == ["covering, lattice"] * n + ["covering"] * (len(after_seed) - n)
