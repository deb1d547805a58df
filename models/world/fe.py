"""Axisymmetric linear-elastic finite elements for a rigid frictionless sphere on a bonded layer.

What is solved (docs/physics.md, "The world"): a layer of thickness t in cylindrical coordinates
(rho, z), z up, table at z = 0, bonded to it (u = 0 at z = 0), u_rho = 0 on the axis, traction-free
top except under a rigid frictionless sphere of radius 1 (lengths are in units of the sphere radius)
pressed d below the undeformed surface; the outer wall rho = L is traction-free. Material: E and nu
of the background, optionally a coaxial stiff (or soft) cylinder of radius R_inc whose top lies
``top`` below the surface and which runs down to the table (or ``bottom`` below the surface).

Elements: Taylor-Hood (quadratic displacement, linear pressure) on a graded tensor mesh of triangles,
a mixed u-p form that neither locks nor breaks at nu = 0.5. Contact: a primal-dual active set on the
top surface's u_z dofs; active dofs have u_z = -d + (1 - sqrt(1 - rho^2)) (exact sphere gap, small
strain), the others are free; iterate until every active dof pushes on the sphere and no free one
penetrates it. Returns F / (E r^2), the dimensionless force.

Only ``build_tables`` and the table check test import this (it needs scikit-fem); the world at run
time reads the shipped tables.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.sparse.linalg import splu
from skfem import (
    Basis,
    BilinearForm,
    ElementTriP0,
    ElementTriP1,
    ElementTriP2,
    ElementVector,
    MeshTri,
    asm,
)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Layer:
    """One axisymmetric case, lengths over the sphere radius; ratio = E_inc / E (1: no inclusion)."""

    thickness: float
    nu: float
    inc_radius: float = 0.0
    inc_top: float = 0.0
    inc_bottom: float | None = None  # below the surface; None: down to the table
    ratio: float = 1.0
    inc_inner: float = 0.0  # > 0: an annulus inner < rho < radius (checks the offset law)


def graded_nodes(stops: list[float], fine: float, reach: float, end: float) -> FloatArray:
    """Nodes on [0, end]: spacing fine + 0.08 x up to ``reach``, then 25 % growth; ``stops`` kept."""
    pts, x = [0.0], 0.0
    while x < end - 1e-12:
        h = fine + 0.08 * x if x < reach else max(pts[-1] - pts[-2], fine) * 1.25
        x = min(x + h, end)
        if end - x < 0.3 * h:
            x = end
        pts.append(x)
    arr = np.array(pts)
    for s in stops:  # move the nearest node onto each material boundary
        if 0.0 < s < end:
            j = int(np.argmin(np.abs(arr - s)))
            if 0 < j < arr.size - 1:
                arr[j] = s
            else:
                arr = np.sort(np.append(arr, s))
    out: FloatArray = np.unique(arr)
    return out


def make_mesh(layer: Layer, fine: float = 0.02, reach: float = 1.05) -> MeshTri:
    """Graded tensor mesh of [0, L] x [0, t]: spacing ~ fine + 0.08 rho near the axis and the top.

    The spacing grows with the distance from the axis so that small and large contacts (contact
    radius 0.1 to 0.9 of r) are all resolved by about ten cells; beyond ``reach`` it grows 25 % a
    cell to the far wall at L = max(4 t + 6, 12).
    """
    t = layer.thickness
    length = max(4.0 * t + 6.0, 12.0)
    rstops = [layer.inc_radius, layer.inc_inner] if layer.ratio != 1.0 else []
    zstops = []
    if layer.ratio != 1.0:
        zstops.append(t - layer.inc_top)
        if layer.inc_bottom is not None:
            zstops.append(t - layer.inc_bottom)
    rho = graded_nodes(rstops, fine, reach, length)
    # z measured down from the top surface, then flipped so that the table is z = 0
    down = graded_nodes([t - s for s in zstops], fine, min(reach, t), t)
    z = np.sort(t - down)
    return MeshTri.init_tensor(rho, z)


@BilinearForm
def _shear(u, v, w):  # type: ignore[no-untyped-def]
    r = w.x[0]
    eu = (u.grad[0, 0], u.grad[1, 1], u[0] / r, u.grad[0, 1] + u.grad[1, 0])
    ev = (v.grad[0, 0], v.grad[1, 1], v[0] / r, v.grad[0, 1] + v.grad[1, 0])
    dev = eu[0] * ev[0] + eu[1] * ev[1] + eu[2] * ev[2] + 0.5 * eu[3] * ev[3]
    return 2.0 * w.mu * dev * r


@BilinearForm
def _div(p, v, w):  # type: ignore[no-untyped-def]
    r = w.x[0]
    return -p * (v.grad[0, 0] + v.grad[1, 1] + v[0] / r) * r


@BilinearForm
def _compliance(p, q, w):  # type: ignore[no-untyped-def]
    return -p * q * w.inv_lam * w.x[0]


class AxisymmetricContact:
    """The assembled layer, condensed onto the top surface's u_z dofs near the axis.

    One sparse LU of the stiffness (everything but the candidate contact dofs) gives the surface
    stiffness matrix S of those dofs; every depth's active-set iteration is then a small dense solve.
    """

    def __init__(self, layer: Layer, fine: float = 0.02, reach: float = 1.05) -> None:
        self.layer = layer
        self.mesh = mesh = make_mesh(layer, fine, reach)
        self.basis = bu = Basis(mesh, ElementVector(ElementTriP2()), intorder=4)
        bp = bu.with_element(ElementTriP1())
        b0 = bu.with_element(ElementTriP0())
        centre = mesh.p[:, mesh.t].mean(axis=1)
        depth_below = layer.thickness - centre[1]
        bottom = layer.thickness if layer.inc_bottom is None else layer.inc_bottom
        inside = (
            (centre[0] < layer.inc_radius)
            & (centre[0] > layer.inc_inner)
            & (depth_below > layer.inc_top)
            & (depth_below < bottom)
        )
        self.modulus = np.where(inside, layer.ratio, 1.0)
        nu = layer.nu
        mu = self.modulus / (2.0 * (1.0 + nu))
        inv_lam = (1.0 + nu) * (1.0 - 2.0 * nu) / (self.modulus * nu)
        a = asm(_shear, bu, mu=b0.interpolate(mu))
        b = asm(_div, bp, bu)
        c = asm(_compliance, bp, inv_lam=b0.interpolate(inv_lam))
        k = sp.bmat([[a, b], [b.T, c]], format="csr")
        n = k.shape[0]
        ur, uz = bu.split_indices()
        x = bu.doflocs
        t = layer.thickness
        fixed = np.concatenate([ur[np.isclose(x[1, ur], 0.0)], uz[np.isclose(x[1, uz], 0.0)]])
        fixed = np.unique(np.concatenate([fixed, ur[np.isclose(x[0, ur], 0.0)]]))
        cand = uz[np.isclose(x[1, uz], t) & (x[0, uz] <= reach)]
        self.cand = cand[np.argsort(x[0, cand])]
        self.rho = x[0, self.cand]
        free = np.setdiff1d(np.arange(n), np.concatenate([fixed, self.cand]))
        lu = splu(k[free][:, free].tocsc())
        k_fc = k[free][:, self.cand].toarray()
        self._lift = -lu.solve(k_fc)  # u_free = lift @ u_cand
        self.stiffness = k[self.cand][:, self.cand].toarray() + k_fc.T @ self._lift
        self._free, self._n = free, n

    def solve(self, depth: float, max_iter: int = 60) -> tuple[float, FloatArray]:
        """(F / (E r^2), u_z of the candidate dofs) for the sphere pressed ``depth`` (over r)."""
        s = self.stiffness
        gap = 1.0 - np.sqrt(np.clip(1.0 - self.rho**2, 0.0, None))
        target = np.where(self.rho < 1.0, -depth + gap, np.inf)
        active = target < 0.0
        for _ in range(max_iter):
            if not active.any():
                active[0] = True
            u = np.where(active, target, 0.0)
            ina = ~active
            if ina.any():
                u[ina] = -np.linalg.solve(s[np.ix_(ina, ina)], s[np.ix_(ina, active)] @ u[active])
            react = s @ u  # nodal force the tissue needs; < 0 where it pushes the sphere up
            new = (active & (react < 0.0)) | (ina & (u > target + 1e-12))
            if np.array_equal(new, active):
                return float(-2.0 * np.pi * react[active].sum()), u
            active = new
        raise RuntimeError(f"contact active set did not converge for {self.layer}, d={depth}")

    def force(self, depth: float) -> float:
        """F / (E r^2) for the sphere pressed ``depth`` (over r) into the layer."""
        return self.solve(depth)[0]

    def field(self, u_cand: FloatArray) -> FloatArray:
        """The full displacement (and pressure) vector for given candidate-dof displacements."""
        full = np.zeros(self._n)
        full[self.cand] = u_cand
        full[self._free] = self._lift @ u_cand
        return full


def solve_forces(layer: Layer, depths: FloatArray, fine: float = 0.02) -> FloatArray:
    """F / (E r^2) at each depth (over r) for one layer."""
    model = AxisymmetricContact(layer, fine)
    return np.array([model.force(float(d)) for d in depths])
