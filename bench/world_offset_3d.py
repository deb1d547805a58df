"""A few 3-D finite-element solves of an inclusion beside the indenter, against the world's tables.

The world solves inclusions on the axis only (axisymmetric) and spreads them to lateral offsets by
the share of the indentation's strain energy they hold (docs/physics.md, "The world"). Here a
coarse 3-D model (scikit-fem, Taylor-Hood tetrahedra, half space by the y = 0 symmetry plane,
rigid frictionless sphere by the same condensed active set as the axisymmetric solver) solves the
reference layer of issue 14 with the 6 mm x6 inclusion at several lateral offsets; each contrast is
F(inclusion) / F(no inclusion) on the same mesh, so most discretisation error cancels.

    nice python -m bench.world_offset_3d [--fine 0.2] [--inclusion 6 6]

prints, per offset, the 3-D FE contrast and the world's (TissueWorld through the shipped tables).
A few CPU-minutes; a finer mesh is slower and needs more memory.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from skfem import (
    Basis,
    BilinearForm,
    ElementTetP0,
    ElementTetP1,
    ElementTetP2,
    ElementVector,
    MeshTet,
    asm,
)
from skfem.helpers import ddot, sym_grad, trace

from models.phantom import parse_phantom
from models.world import TissueWorld
from models.world.fe import graded_nodes

R_MM, E_KPA, NU, T_MM, TOP_MM = 4.0, 26.4, 0.49, 3.68, 2.0


@BilinearForm
def _shear(u, v, w):  # type: ignore[no-untyped-def]
    return 2.0 * w.mu * ddot(sym_grad(u), sym_grad(v))


@BilinearForm
def _div(p, v, w):  # type: ignore[no-untyped-def]
    return -p * trace(sym_grad(v))


@BilinearForm
def _compliance(p, q, w):  # type: ignore[no-untyped-def]
    return -p * q * w.inv_lam


def contrast_3d(
    offsets: list[float], rad: float, ratio: float, depth: float, fine: float
) -> list[float]:
    """F(inclusion at each offset) / F(none), all lengths over the sphere radius."""
    t = T_MM / R_MM
    half = graded_nodes([], fine, 1.1, 4.5)
    xs = np.concatenate([-half[::-1], half[1:]])
    z = np.sort(t - graded_nodes([TOP_MM / R_MM], fine, min(1.1, t), t))  # fine at the top
    mesh = MeshTet.init_tensor(xs, half, z)
    bu = Basis(mesh, ElementVector(ElementTetP2()), intorder=4)
    bp, b0 = bu.with_element(ElementTetP1()), bu.with_element(ElementTetP0())
    dofs = bu.split_indices()
    x = bu.doflocs
    fixed = np.unique(
        np.concatenate(
            [*(d[np.isclose(x[2, d], 0.0)] for d in dofs), dofs[1][np.isclose(x[1, dofs[1]], 0.0)]]
        )
    )
    uz = dofs[2]
    cand = uz[np.isclose(x[2, uz], t) & (x[0, uz] ** 2 + x[1, uz] ** 2 < 1.05**2)]
    rho = np.hypot(x[0, cand], x[1, cand])
    centre = mesh.p[:, mesh.t].mean(axis=1)
    b = asm(_div, bp, bu)
    out = []
    for off in [None, *offsets]:
        inside = (
            np.zeros(mesh.t.shape[1], bool)
            if off is None
            else ((np.hypot(centre[0] - off, centre[1]) < rad) & (t - centre[2] > TOP_MM / R_MM))
        )
        e = np.where(inside, ratio, 1.0)
        a = asm(_shear, bu, mu=b0.interpolate(e / (2 * (1 + NU))))
        c = asm(_compliance, bp, inv_lam=b0.interpolate((1 + NU) * (1 - 2 * NU) / (e * NU)))
        k = sp.bmat([[a, b], [b.T, c]], format="csr")
        free = np.setdiff1d(np.arange(k.shape[0]), np.concatenate([fixed, cand]))
        lu = splu(k[free][:, free].tocsc())
        k_fc = k[free][:, cand].toarray()
        s = k[cand][:, cand].toarray() - k_fc.T @ lu.solve(k_fc)
        target = -depth + 1.0 - np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
        active = target < 0
        for _ in range(60):
            u = np.where(active, target, 0.0)
            ina = ~active
            u[ina] = -np.linalg.solve(s[np.ix_(ina, ina)], s[np.ix_(ina, active)] @ u[active])
            react = s @ u
            new = (active & (react < 0)) | (ina & (u > target + 1e-12))
            if np.array_equal(new, active):
                break
            active = new
        out.append(float(-react[active].sum()))
    return [f / out[0] for f in out[1:]]


def main() -> None:
    """Solve the offsets and print 3-D FE against the world."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--fine", type=float, default=0.2, help="mesh spacing at the axis, over r")
    p.add_argument(
        "--inclusion", type=float, nargs=2, default=(6.0, 6.0), metavar=("R_MM", "RATIO")
    )
    args = p.parse_args()
    t0 = time.process_time()
    (rad_mm, ratio), depth_mm = args.inclusion, 1.0
    offsets_mm = [0.0, rad_mm - 2.0, rad_mm, rad_mm + 2.0, rad_mm + 4.0]
    fe = contrast_3d(
        [o / R_MM for o in offsets_mm], rad_mm / R_MM, ratio, depth_mm / R_MM, args.fine
    )
    base = {
        "size_mm": [60, 60],
        "thickness_mm": T_MM,
        "youngs_modulus_kpa": E_KPA,
        "poisson_ratio": NU,
    }
    inc = {
        "center_mm": [30, 30],
        "radius_mm": rad_mm,
        "depth_mm": TOP_MM,
        "youngs_modulus_kpa": ratio * E_KPA,
    }
    world, plain = (
        TissueWorld(parse_phantom(base | {"inclusions": [inc]})),
        TissueWorld(parse_phantom(base)),
    )
    print(
        f"{rad_mm} mm x{ratio} inclusion, 3.68 mm layer, r = 4 mm, d = 1 mm, "
        f"3-D mesh spacing {args.fine} r"
    )
    print("offset mm   3-D FE   world   excess error")
    for o, c in zip(offsets_mm, fe, strict=True):
        w = float(world.force_n(30 + o, 30, depth_mm)) / float(plain.force_n(30 + o, 30, depth_mm))
        print(f"{o:9.1f}  {c:7.3f}  {w:6.3f}   {(w - 1) / (c - 1) - 1:+6.1%}")
    print(f"{time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
