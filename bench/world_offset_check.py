"""How good is the world's reduction of off-axis and short inclusions? Axisymmetric FE says.

The world (models/world) solves inclusions only on the indenter's axis and down to the table, and
spreads that excess force to other shapes by the share of the indentation's strain energy the
inclusion holds (docs/physics.md, "The world"). Two shapes that axisymmetric FE can solve exactly
test that premise:

- an annulus rho1 < rho < rho2 around the indenter (stiff material away from the axis, as an
  inclusion at a lateral offset puts it): FE excess vs (disc excess) x (energy share of the ring);
- a short cylinder (top..bottom) vs (down-to-table excess) x (energy share of its height).

    nice python -m bench.world_offset_check

prints one row per case: FE contrast, predicted contrast, and the error of the excess.
"""

from __future__ import annotations

import time

import numpy as np

from models.world.build_tables import energy_bins
from models.world.fe import AxisymmetricContact, Layer

EDGES = np.linspace(0.0, 60.0, 3001)
MID = 0.5 * (EDGES[1:] + EDGES[:-1])


def _share(
    plain: AxisymmetricContact, depth: float, inner: float, outer: float, z0: float, z1: float
) -> float:
    """Energy (fraction of the total) in inner < rho < outer between depths z0 and z1 (over t)."""
    _, u = plain.solve(depth)
    bins = energy_bins(plain, u, EDGES)
    z = np.linspace(0.0, 1.0, 11)
    k0, k1 = int(round(z0 * 10)), int(round(z1 * 10))
    assert np.isclose(z[k0], z0) and np.isclose(z[k1], z1), "z0, z1 must be tenths of t"
    mid = MID
    ring = (mid > inner) & (mid < outer)
    return float(bins[ring, k1].sum() - bins[ring, k0].sum())


def main() -> None:
    """Run the cases and print the table (CPU time at the end)."""
    t0 = time.process_time()
    nu, depth = 0.49, 0.25
    print("case                                   FE       predicted  excess error")
    for t, k in [(0.92, 6.0), (2.5, 4.0)]:
        plain = AxisymmetricContact(Layer(t, nu))
        f0 = plain.force(depth)
        top = 0.2 * t
        for inner, outer in [(0.0, 1.0), (0.5, 1.5), (1.0, 2.0), (1.5, 2.5), (2.5, 3.5)]:
            ring = AxisymmetricContact(Layer(t, nu, outer, top, None, k, inner)).force(depth) / f0
            disc = AxisymmetricContact(Layer(t, nu, outer, top, None, k)).force(depth) / f0
            share = _share(plain, depth, inner, outer, 0.2, 1.0) / _share(
                plain, depth, 0.0, outer, 0.2, 1.0
            )
            pred = 1.0 + (disc - 1.0) * share
            err = (pred - 1.0) / (ring - 1.0) - 1.0
            print(
                f"t={t} k={k} ring {inner:.1f}-{outer:.1f}          {ring:7.4f}  {pred:7.4f}    {err:+6.1%}"
            )
        for bottom in (0.4, 0.6, 0.8):
            short = AxisymmetricContact(Layer(t, nu, 1.5, top, bottom * t, k)).force(depth) / f0
            full = AxisymmetricContact(Layer(t, nu, 1.5, top, None, k)).force(depth) / f0
            share = _share(plain, depth, 0.0, 1.5, 0.2, bottom) / _share(
                plain, depth, 0.0, 1.5, 0.2, 1.0
            )
            pred = 1.0 + (full - 1.0) * share
            err = (pred - 1.0) / (short - 1.0) - 1.0
            print(
                f"t={t} k={k} R=1.5 depth 0.2t-{bottom:.1f}t     {short:7.4f}  {pred:7.4f}    {err:+6.1%}"
            )
    print(f"{time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
