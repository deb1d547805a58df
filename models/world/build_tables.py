"""Regenerate the world's shipped tables: ``nice python -m models.world.build_tables [--out PATH]``.

Everything is dimensionless (lengths over the sphere radius r, force over E r^2), solved by
``models.world.fe`` (axisymmetric, Taylor-Hood, active-set contact). Three tables:

- ``hom_force[nu, t, d]``: F / (E r^2) of a homogeneous bonded layer of thickness t at depth d.
- ``contrast[nu, t, d, s, R, k]``: F(with inclusion) / F(without) for a coaxial cylinder of radius R
  and stiffness ratio k whose top lies s * t below the surface, down to the table.
- ``energy[nu, t, d, R, e, z]``: the fraction of the homogeneous indentation's strain energy that
  lies inside a vertical cylinder of radius R whose axis is R + e from the indenter's, between the
  surface and the depth z * t. The world spreads an inclusion's on-axis excess force over lateral
  offsets and finite heights with it (docs/physics.md, "The world").

The script prints its CPU time; the grids below are the shipped ones.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from models.world.fe import AxisymmetricContact, FloatArray, Layer

TABLE_PATH = Path(__file__).with_name("tables.npz")

HOM_NU = np.array([0.3, 0.4, 0.45, 0.48, 0.49, 0.5])
HOM_T = np.array([0.4, 0.5, 0.7, 1.0, 1.4, 2.0, 3.0, 5.0, 8.0, 12.0])
HOM_D = np.geomspace(0.01, 1.0, 15)
C_NU = np.array([0.45, 0.49, 0.5])
C_T = np.array([0.4, 0.7, 1.0, 1.5, 2.5, 5.0])
C_D = np.array([0.05, 0.1, 0.2, 0.35, 0.6, 1.0])
C_S = np.array([0.0, 0.15, 0.35, 0.6, 1.0])  # 1.0: the inclusion is gone, contrast 1 (not solved)
C_R = np.array([0.25, 0.5, 1.0, 1.5, 2.5, 4.0])
C_K = np.array([0.5, 1.0, 2.0, 4.0, 8.0, 16.0])  # 1.0: no inclusion (not solved)
E_OFF = np.concatenate([np.arange(-4.0, 3.0, 0.2), np.arange(3.0, 10.01, 0.5)])
E_Z = np.linspace(0.0, 1.0, 11)
FINE = 0.03  # mesh spacing at the axis (over r); 0.02 for the homogeneous table


def ring_fraction(rho: FloatArray, offset: float, radius: float) -> FloatArray:
    """Fraction of the circle of radius rho (about the indenter) inside a disc R at distance l."""
    rho = np.maximum(rho, 1e-12)
    if offset <= 1e-12:
        out: FloatArray = (rho < radius).astype(float)
        return out
    cos = (rho**2 + offset**2 - radius**2) / (2.0 * rho * offset)
    frac = np.arccos(np.clip(cos, -1.0, 1.0)) / np.pi
    return np.where(rho + offset <= radius, 1.0, frac)


def energy_bins(
    model: AxisymmetricContact, u_cand: FloatArray, rho_edges: FloatArray
) -> FloatArray:
    """Strain energy of the solved field binned by rho (rows) and by depth below z * t (cumulative)."""
    layer = model.layer
    bu = model.basis
    full = model.field(u_cand)
    f = bu.interpolate(full[: bu.N])
    x = bu.mapping.F(bu.X)  # (2, nelem, nqp) quadrature point coordinates
    r = x[0]
    g, v = f.grad, np.asarray(f)
    err, ezz, ett, grz = g[0, 0], g[1, 1], v[0] / r, g[0, 1] + g[1, 0]
    e = model.modulus[:, None]
    mu = e / (2.0 * (1.0 + layer.nu))
    lam = e * layer.nu / ((1.0 + layer.nu) * (1.0 - 2.0 * layer.nu)) if layer.nu < 0.5 else None
    dens = mu * (err**2 + ezz**2 + ett**2 + 0.5 * grz**2)
    if lam is not None:
        dens = dens + 0.5 * lam * (err + ezz + ett) ** 2
    w = (dens * 2.0 * np.pi * r * bu.dx).ravel()
    depth = (layer.thickness - x[1]).ravel() / layer.thickness
    ib = np.clip(np.searchsorted(rho_edges, r.ravel()) - 1, 0, rho_edges.size - 2)
    out = np.zeros((rho_edges.size - 1, E_Z.size))
    for k, z in enumerate(E_Z):
        sel = depth <= z + 1e-9
        out[:, k] = np.bincount(ib[sel], w[sel], minlength=rho_edges.size - 1)
    total: float = w.sum()
    res: FloatArray = out / total
    return res


def build(log: bool = True) -> dict[str, FloatArray]:
    """Solve every case of the shipped grids; returns the arrays of tables.npz."""
    hom = np.zeros((HOM_NU.size, HOM_T.size, HOM_D.size))
    for i, nu in enumerate(HOM_NU):
        for j, t in enumerate(HOM_T):
            model = AxisymmetricContact(Layer(float(t), float(nu)), fine=0.02)
            hom[i, j] = [model.force(float(d)) for d in HOM_D]
    if log:
        print(f"homogeneous table done, {time.process_time():.0f} s CPU", file=sys.stderr)
    contrast = np.ones((C_NU.size, C_T.size, C_D.size, C_S.size, C_R.size, C_K.size))
    energy = np.zeros((C_NU.size, C_T.size, C_D.size, C_R.size, E_OFF.size, E_Z.size))
    rho_edges = np.linspace(0.0, 60.0, 3001)
    rho_mid = 0.5 * (rho_edges[1:] + rho_edges[:-1])
    for i, nu in enumerate(C_NU):
        for j, t in enumerate(C_T):
            base = AxisymmetricContact(Layer(float(t), float(nu)), fine=FINE)
            f0 = []
            for a, d in enumerate(C_D):
                f, u = base.solve(float(d))
                f0.append(f)
                bins = energy_bins(base, u, rho_edges)
                for b, rad in enumerate(C_R):
                    for c, e in enumerate(E_OFF):
                        frac = ring_fraction(rho_mid, max(float(rad + e), 0.0), float(rad))
                        energy[i, j, a, b, c] = frac @ bins
            for si, s in enumerate(C_S[:-1]):
                for b, rad in enumerate(C_R):
                    for c, k in enumerate(C_K):
                        if k == 1.0:
                            continue
                        layer = Layer(float(t), float(nu), float(rad), float(s * t), None, float(k))
                        model = AxisymmetricContact(layer, fine=FINE)
                        contrast[i, j, :, si, b, c] = [
                            model.force(float(d)) / f for d, f in zip(C_D, f0, strict=True)
                        ]
            if log:
                print(f"nu={nu} t={t} done, {time.process_time():.0f} s CPU", file=sys.stderr)
    return {
        "hom_nu": HOM_NU, "hom_t": HOM_T, "hom_d": HOM_D, "hom_force": hom,
        "c_nu": C_NU, "c_t": C_T, "c_d": C_D, "c_s": C_S, "c_r": C_R, "c_k": C_K,
        "contrast": contrast, "e_off": E_OFF, "e_z": E_Z, "energy": energy.astype(np.float32),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Build the tables and write them (default: next to this module, where the world reads them)."""
    p = argparse.ArgumentParser(prog="python -m models.world.build_tables", description=__doc__)
    p.add_argument(
        "--out", type=Path, default=TABLE_PATH, help="output .npz (default: %(default)s)"
    )
    args = p.parse_args(argv)
    t0 = time.process_time()
    tables = build()
    np.savez_compressed(args.out, **tables)  # type: ignore[arg-type]
    print(f"wrote {args.out} in {time.process_time() - t0:.0f} s CPU", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
