"""The camera probe's simulated world: four tips on springs pressing one sample (issue 14, item 3).

This is the truth the sim camera renders; it shares no formula with the estimator (eq. 5 in
``models.multi_indenter``, whose solver this module never calls). What it models:

* **The probe as built** (:class:`ProbeBuild`): each indenter's real spring constant, each
  marker's real image scale (px/mm), the Coulomb friction of each indenter in its guide, and the
  camera's radial lens distortion. :meth:`ProbeBuild.draw` makes one probe from
  :class:`ProbeErrorSpec` and a seeded generator; :meth:`ProbeBuild.ideal` is the nominal probe
  (tests of the estimator's algebra only).
* **What each tip presses.** A spring sample (paper 2, Table I): under every tip one rod on its
  own spring, force K_rod * indentation, no coupling between rods. The rods stay parallel to
  the indenters (the paper: the samples have "the same structure as the indenters", each
  indenter on its rod), so an inclined sample is a sample whose rod heads lie on an inclined
  plane. A tissue phantom: the force each tip feels at its own location and indentation comes
  from a :class:`TipForce` (the FE-grounded tissue world), and the tips are elastically coupled
  through the tissue (below).
* **Equilibrium** of every indenter, solved jointly each frame (:meth:`CameraWorld.press`):
  spring force k_i dx_i, guide friction |F_i - k_i dx_i| <= f_i (stick inside the band, slide at
  its edge: pressing leaves the springs short of the tissue force by f_i, releasing by -f_i), the
  stroke end (dx_i <= stroke), and the tissue indentation
  delta_i = overlap_i - dx_i - sum_j g(rho_ij) F_j.

Coupling law (tissue only). A tip's load F_j lowers the free surface at distance rho by
g(rho) F_j. For a homogeneous layer of thickness h bonded to a rigid table, loaded by a point
force on its frictionless surface, the surface deflection is the Hankel integral

    w(rho) = F (1 - nu^2) / (pi E) * integral_0^inf K(k h) J0(k rho) dk,
    K(t) = (2 kappa sinh 2t - 4 t) / (2 kappa cosh 2t + 4 t^2 + 1 + kappa^2),  kappa = 3 - 4 nu,

K -> 1 being Boussinesq's half-space (w = F (1 - nu^2) / (pi E rho); Johnson, *Contact
Mechanics*, 1985, eq. 3.20b) and K(t) the bonded-layer kernel of Hayes, Keer, Herrmann and
Mockros (J. Biomech. 5, 1972, 541-551). Checks in the tests: the half-space limit, and the thin
layer's limit w = p h (1 + nu)(1 - 2 nu) / ((1 - nu) E) (confined compression). The neighbour's
deflection is taken as a rigid shift of the surface under tip i (rho = 8 mm is four tip-contact
radii and more), E is the background modulus and h the thickness under the probe centre.

Pure: no I/O; randomness only from the generator given to :meth:`ProbeBuild.draw`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any, Literal, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt
from scipy import integrate, special

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DEFAULT_ERRORS",
    "CameraWorld",
    "ContactState",
    "ProbeBuild",
    "ProbeErrorSpec",
    "SpringRods",
    "TipForce",
    "TissueTips",
    "layer_deflection_factor",
    "layer_kernel",
]


@dataclass(frozen=True)
class ProbeErrorSpec:
    """Manufacturing and camera errors of one probe, as the ranges a draw picks from.

    spring_tolerance: relative tolerance band of each spring's constant (commercial compression
    springs: +-5 to +-10 %); scale_tolerance: relative band of each marker's px/mm (the spheres sit
    at slightly different distances from the 7 mm camera). ``spread`` says how a part falls in its
    band: ``normal``, a process just capable of it (Cp = 1: sigma = band / 3, clipped at the band),
    or ``uniform`` anywhere in it (the pessimistic reading). friction_n: range of each indenter's
    Coulomb friction in its 3-D printed guide (N, uniform); distortion_k1: range of the radial
    distortion coefficient (barrel < 0, uniform) with radii normalised by ``focal_px``.
    """

    spring_tolerance: float = 0.08
    scale_tolerance: float = 0.02
    friction_n: tuple[float, float] = (0.002, 0.008)
    distortion_k1: tuple[float, float] = (-0.08, -0.02)
    focal_px: float = 600.0
    spread: Literal["normal", "uniform"] = "normal"

    def relative_errors(self, band: float, n: int, rng: np.random.Generator) -> FloatArray:
        """n relative errors within +-band, drawn as ``spread`` says."""
        if self.spread == "uniform":
            return rng.uniform(-band, band, n)
        out: FloatArray = np.clip(rng.normal(0.0, band / 3.0, n), -band, band)
        return out


DEFAULT_ERRORS = ProbeErrorSpec()


@dataclass(frozen=True)
class ProbeBuild:
    """One probe as manufactured: the truth behind its nominal design (mm, N/mm, px/mm, N)."""

    x_mm: tuple[float, ...]
    y_mm: tuple[float, ...]
    k_n_per_mm: tuple[float, ...]
    px_per_mm: tuple[float, ...]
    friction_n: tuple[float, ...]
    distortion_k1: float = 0.0
    focal_px: float = 600.0
    stroke_mm: float = 10.0
    tip_radius_mm: float = 2.0

    def __post_init__(self) -> None:
        n = len(self.x_mm)
        for name in ("y_mm", "k_n_per_mm", "px_per_mm", "friction_n"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"ProbeBuild.{name}: expected {n} values (one per indenter)")
        if not all(k > 0 for k in self.k_n_per_mm) or not all(s > 0 for s in self.px_per_mm):
            raise ValueError("ProbeBuild: spring constants and scales must be > 0")
        if not all(f >= 0 for f in self.friction_n):
            raise ValueError(f"ProbeBuild.friction_n: must be >= 0, got {self.friction_n}")

    @property
    def n(self) -> int:
        """Number of indenters."""
        return len(self.x_mm)

    @classmethod
    def ideal(cls, x_mm: Sequence[float], y_mm: Sequence[float], k_n_per_mm: Sequence[float],
              px_per_mm: float, stroke_mm: float = 10.0) -> ProbeBuild:
        """The nominal probe: exact springs and scale, no friction, no distortion (unit tests only)."""
        n = len(x_mm)
        return cls(tuple(x_mm), tuple(y_mm), tuple(k_n_per_mm), (float(px_per_mm),) * n, (0.0,) * n,
                   stroke_mm=stroke_mm)

    @classmethod
    def draw(cls, x_mm: Sequence[float], y_mm: Sequence[float], k_n_per_mm: Sequence[float],
             px_per_mm: float, spec: ProbeErrorSpec, rng: np.random.Generator,
             stroke_mm: float = 10.0) -> ProbeBuild:
        """One manufactured probe: every error drawn uniformly from ``spec``'s ranges."""
        n = len(x_mm)
        k = np.asarray(k_n_per_mm) * (1.0 + spec.relative_errors(spec.spring_tolerance, n, rng))
        s = px_per_mm * (1.0 + spec.relative_errors(spec.scale_tolerance, n, rng))
        f = rng.uniform(*spec.friction_n, n)
        k1 = float(rng.uniform(*spec.distortion_k1))
        return cls(tuple(x_mm), tuple(y_mm), tuple(k.tolist()), tuple(s.tolist()), tuple(f.tolist()), k1,
                   spec.focal_px, stroke_mm)

    def to_dict(self) -> dict[str, Any]:
        """Plain values, for the run's record (the node logs them at start)."""
        return asdict(self)


class TipForce(Protocol):
    """The tissue world's force on one tip: ``force_n(x, y, depth_mm, indenter_radius_mm=...)``.

    x, y (mm, phantom frame) and depth (mm below the free surface, >= 0) broadcast; returns N.
    """

    def force_n(self, x_mm: Any, y_mm: Any, depth_mm: Any, *, indenter_radius_mm: float = ...) -> Any: ...


def layer_kernel(t: float, nu: float) -> float:
    """K(t) of a layer bonded to a rigid table (t = wavenumber x thickness); 1 is the half-space."""
    if t > 30.0:
        return 1.0
    kappa = 3.0 - 4.0 * nu
    c, s = math.cosh(2 * t), math.sinh(2 * t)
    return (2 * kappa * s - 4 * t) / (2 * kappa * c + 4 * t * t + 1 + kappa * kappa)


@lru_cache(maxsize=16)
def _layer_table(nu: float) -> tuple[FloatArray, FloatArray]:
    """rho/h grid and Phi(rho/h) = layer deflection / half-space deflection at that distance."""
    r = np.geomspace(1e-3, 40.0, 140)

    def excess(t: float) -> float:  # K(t) - 1, which decays like exp(-2t)
        return layer_kernel(t, nu) - 1.0

    phi = np.empty_like(r)
    for i, x in enumerate(r):
        # in units of h: w rho (pi E / F (1 - nu^2)) = 1 + x * int_0^inf (K(t) - 1) J0(t x) dt
        val, _ = integrate.quad(lambda t, x=x: excess(t) * float(special.j0(t * x)), 0.0, 30.0, limit=400)
        phi[i] = 1.0 + x * val
    return r, phi


def layer_deflection_factor(rho_mm: Any, thickness_mm: float, nu: float) -> Any:
    """Phi: surface deflection at ``rho`` from a point load on a bonded layer / Boussinesq's."""
    r, phi = _layer_table(round(float(nu), 4))
    x = np.asarray(rho_mm, dtype=np.float64) / thickness_mm
    return np.interp(np.log(np.clip(x, r[0], r[-1])), np.log(r), phi)


#: Indentations (mm) at which a tip's force is tabulated once per probe position; dense near 0.
DEPTH_GRID_MM = 15.0 * np.linspace(0.0, 1.0, 97) ** 2


class _Tabulated:
    """A sample as the tips meet it: per tip, force (N) against indentation on ``DEPTH_GRID_MM``
    (linear between nodes, at the last slope beyond), and the coupling matrix g (mm/N)."""

    table: FloatArray
    coupling: FloatArray

    def _finish(self, table: FloatArray, coupling: FloatArray) -> None:
        self.table = table
        self._slope = np.diff(table, axis=1) / np.diff(DEPTH_GRID_MM)
        self.coupling = coupling

    def force(self, delta_mm: FloatArray, rows: npt.NDArray[np.intp]) -> FloatArray:
        """Forces (N) on the tips ``rows`` for indentations delta (mm; <= 0: no contact)."""
        grid = DEPTH_GRID_MM
        d = np.clip(delta_mm, 0.0, None)
        seg = np.clip(np.searchsorted(grid, d, side="right") - 1, 0, grid.size - 2)
        out: FloatArray = self.table[rows, seg] + self._slope[rows, seg] * (d - grid[seg])
        return out

    def compression(self, reach: FloatArray, k: FloatArray, target: FloatArray,
                    rows: npt.NDArray[np.intp]) -> FloatArray:
        """The spring compression dx where F(reach - dx) - k dx = target, per entry (exact on the table).

        h rises with the indentation delta = reach - dx; it is linear between the table's nodes, so
        the root is found by locating the sign change and interpolating. With no contact (delta <= 0)
        F = 0 and dx = -target / k.
        """
        grid = DEPTH_GRID_MM
        h = self.table[rows] - k[:, None] * (reach[:, None] - grid[None, :]) - target[:, None]
        above = h >= 0
        first = np.argmax(above, axis=1)
        any_above = above.any(axis=1)
        g1 = np.clip(first, 1, grid.size - 1)
        i = np.arange(len(rows))
        h0, h1 = h[i, g1 - 1], h[i, g1]
        inside = grid[g1 - 1] + (-h0) * (grid[g1] - grid[g1 - 1]) / np.where(h1 > h0, h1 - h0, 1.0)
        beyond = grid[-1] + (-h[:, -1]) / (self._slope[rows, -1] + k)
        delta = np.where(any_above, inside, beyond)
        out: FloatArray = np.where(any_above & (first == 0), -target / k, reach - delta)
        return out


class SpringRods(_Tabulated):
    """A spring sample: one rod of ``k_n_per_mm[i]`` under tip i, no coupling between rods."""

    def __init__(self, k_n_per_mm: Sequence[float]) -> None:
        k = np.asarray(k_n_per_mm, dtype=np.float64)
        self._finish(k[:, None] * DEPTH_GRID_MM[None, :], np.zeros((k.size, k.size)))


class TissueTips(_Tabulated):
    """Tissue under the four tips: ``world.force_n`` at each tip, coupled through the layer.

    The world is asked once, for every tip over ``DEPTH_GRID_MM`` (one vectorised call); the
    equilibrium then works on that table.
    """

    def __init__(self, world: TipForce, x_mm: Sequence[float], y_mm: Sequence[float], tip_radius_mm: float,
                 youngs_modulus_kpa: float, poisson_ratio: float, thickness_mm: float) -> None:
        x = np.asarray(x_mm, dtype=np.float64)
        y = np.asarray(y_mm, dtype=np.float64)
        grid = DEPTH_GRID_MM
        f = np.asarray(world.force_n(np.repeat(x, grid.size), np.repeat(y, grid.size), np.tile(grid, x.size),
                                     indenter_radius_mm=tip_radius_mm), dtype=np.float64)
        rho = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
        e_star = youngs_modulus_kpa * 1e-3 / (1.0 - poisson_ratio**2)  # N/mm^2
        with np.errstate(divide="ignore"):
            g = layer_deflection_factor(rho, thickness_mm, poisson_ratio) / (math.pi * e_star * rho)
        np.fill_diagonal(g, 0.0)
        # g[i, j]: surface deflection (mm) at tip i per newton on tip j (zero diagonal)
        self._finish(np.nan_to_num(f.reshape(x.size, grid.size), nan=0.0), g)


class ContactState(NamedTuple):
    """One equilibrium: per tip spring compression dx (mm), indentation (mm), force (N), contact."""

    dx_mm: FloatArray
    indentation_mm: FloatArray
    force_n: FloatArray
    contact: npt.NDArray[np.bool_]


class CameraWorld:
    """The probe ``build`` pressing a sample; remembers the springs' state (friction has memory).

    ``press(overlap_mm, sample)``: overlap_i is how far tip i at rest would sit below the free
    surface (mm, negative: above it). Returns the equilibrium, solved jointly for all tips.
    """

    def __init__(self, build: ProbeBuild) -> None:
        self.build = build
        self.k = np.asarray(build.k_n_per_mm)
        self.f = np.asarray(build.friction_n)
        self.dx = np.zeros(build.n)
        self.load = np.zeros(build.n)

    def reset(self) -> None:
        """Springs back at rest, no load."""
        self.dx[:] = 0.0
        self.load[:] = 0.0

    def _band(self, sample: SpringRods | TissueTips, reach: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Per tip, the compressions dx in [0, stroke] where |F(reach - dx) - k dx| <= f: (lo, hi);
        reach = overlap minus the neighbours' surface deflection."""
        n = self.build.n
        rows = np.concatenate([np.arange(n), np.arange(n)])
        root = sample.compression(np.concatenate([reach, reach]), np.concatenate([self.k, self.k]),
                                  np.concatenate([self.f, -self.f]), rows)
        root = np.clip(root, 0.0, self.build.stroke_mm)
        return root[:n], root[n:]

    def press(self, overlap_mm: npt.ArrayLike, sample: SpringRods | TissueTips) -> ContactState:
        """Equilibrium of the springs, friction, stroke and sample for the tips' overlaps (mm)."""
        overlap = np.asarray(overlap_mm, dtype=np.float64)
        load = self.load.copy()
        dx = self.dx.copy()
        rows = np.arange(self.build.n)
        for _ in range(60):
            reach = overlap - sample.coupling @ load
            lo, hi = self._band(sample, reach)
            new_dx = np.clip(self.dx, lo, hi)
            new_load = sample.force(reach - new_dx, rows)
            done = np.max(np.abs(new_dx - dx)) < 1e-8 and np.max(np.abs(new_load - load)) < 1e-8
            dx, load = new_dx, new_load  # the coupling is weak (g dF/d(delta) << 1): plain iteration converges
            if done:
                break
        self.dx, self.load = dx, load
        indentation = overlap - sample.coupling @ load - dx
        return ContactState(dx.copy(), indentation, load.copy(), load > 0)
