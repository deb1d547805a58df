"""TissueWorld: the force a phantom pushes back on a rigid sphere with, from finite-element tables.

Shares no formula with the estimators (models/contact.py, models/airfloat.py's inversions,
models/multi_indenter.py's eq. 5): every number comes from ``tables.npz``, solved by
``models.world.fe`` and interpolated here. docs/physics.md ("The world") says what is solved, what
is fitted, the ranges and the errors.

Per query point: the homogeneous force of a layer as thick as the phantom is *there* (a domed top
is taken as locally flat), times 1 + the sum over inclusions of each one's excess, where an
inclusion's excess is its on-axis FE contrast minus one, scaled by the share of the indentation's
strain energy its cylinder holds at the actual lateral offset and height, over the share it would
hold on the axis down to the table.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from models._arrays import ArrayLike, FloatArray
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out
from models.airfloat import DEFAULT_INDENTER_RADIUS_MM
from models.phantom import Phantom
from models.world.tables import Grid, Tables, load_tables

MAX_DEPTH_OVER_RADIUS = 1.0  # a hemisphere in contact; deeper is outside the tables
MAX_DEPTH_OVER_THICKNESS = 0.75  # small-strain FE of a layer squeezed further is fiction
MIN_CONTRAST = 0.05  # floor for many soft inclusions whose excesses are summed


class WorldRangeError(ValueError):
    """A query lies outside what the world's tables cover; the message names the value and limit."""


def _check_radius(r: float) -> float:
    if not (np.isfinite(r) and r > 0):
        raise WorldRangeError(f"world: indenter_radius_mm must be finite and > 0, got {r!r}")
    return float(r)


class TissueWorld:
    """The mechanics of one tissue phantom as an indenter meets it.

    ``force_n`` and ``depth_mm`` take x, y (mm) and depth (mm) or force (N) as floats or
    broadcastable arrays and return a float for scalar input; outside the phantom's footprint they
    return nan. Inputs beyond the tables raise ``WorldRangeError`` (see docs/physics.md for ranges).
    """

    def __init__(self, phantom: Phantom, tables: Tables | None = None) -> None:
        if phantom.is_spring_sample:
            raise ValueError(
                f"TissueWorld: phantom {phantom.name or '(unnamed)'} is a spring sample "
                "(spring_constant_n_per_mm); the tissue world needs youngs_modulus_kpa"
            )
        self.phantom = phantom
        self.tables = tables if tables is not None else load_tables()
        tb = self.tables
        nu = phantom.poisson_ratio
        if not tb.hom_nu[0] <= nu <= tb.hom_nu[-1]:
            raise WorldRangeError(
                f"world: poisson_ratio {nu} outside the tables [{tb.hom_nu[0]}, {tb.hom_nu[-1]}]"
            )
        if phantom.inclusions and not tb.c_nu[0] <= nu <= tb.c_nu[-1]:
            raise WorldRangeError(
                f"world: poisson_ratio {nu} outside the inclusion tables "
                f"[{tb.c_nu[0]}, {tb.c_nu[-1]}]"
            )
        self.nu = float(nu)
        self.e_kpa = float(phantom.youngs_modulus_kpa)  # type: ignore[arg-type]
        incs = phantom.inclusions
        self._cx = np.array([i.center_mm[0] for i in incs])
        self._cy = np.array([i.center_mm[1] for i in incs])
        self._rad = np.array([i.radius_mm for i in incs])
        self._top = np.array([i.depth_mm for i in incs])
        self._height = np.array([np.inf if i.height_mm is None else i.height_mm for i in incs])
        ratio = np.array([float(i.youngs_modulus_kpa) for i in incs]) / self.e_kpa  # type: ignore[arg-type]
        low = ratio < tb.c_k[0]
        if low.any():
            i = int(np.argmax(low))
            raise WorldRangeError(
                f"world: inclusions[{i}] stiffness ratio {ratio[i]:.3g} below the tables' "
                f"{tb.c_k[0]} (a much softer inclusion is outside what was solved)"
            )
        self._ratio = np.minimum(ratio, tb.c_k[-1])  # stiffer than the last node: clamped
        self._hom = tb.hom.fix(0, self.nu)
        self._grid_cache: dict[float, tuple[Grid, Grid]] = {}

    # ------------------------------------------------------------------ the forward model

    def _parts(
        self, x: FloatArray, y: FloatArray, d: FloatArray, r: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(homogeneous force N, contrast, per-inclusion excess (n, m)) at flat points, d > 0 mm."""
        tb = self.tables
        t = np.asarray(self.phantom.thickness(x, y), dtype=float)
        tr = np.maximum(t / r, 1e-9)
        dr = d / r
        self._check(x, y, d, t, r)
        # Thicker than the last node: the layer's influence is within the table's own resolution.
        ltr = np.log(np.minimum(tr, tb.hom_t[-1]))
        ldr = np.log(np.maximum(dr, tb.hom_d[0]))
        fhat = np.exp(self._hom(ltr, ldr))
        small = dr < tb.hom_d[0]  # below the first node the layer no longer matters: Hertz's d^1.5
        fhat = np.where(small, fhat * (np.maximum(dr, 0.0) / tb.hom_d[0]) ** 1.5, fhat)
        force = fhat * self.e_kpa * 1e-3 * r * r
        if self._cx.size == 0:
            return force, np.ones_like(force), np.zeros((x.size, 0))
        excess = self._excess(x, y, t, tr, dr, r)
        contrast = np.maximum(1.0 + excess.sum(axis=1), MIN_CONTRAST)
        return force, contrast, excess

    def _excess(
        self, x: FloatArray, y: FloatArray, t: FloatArray, tr: FloatArray, dr: FloatArray, r: float
    ) -> FloatArray:
        """Each inclusion's excess contrast (n points, m inclusions) at the query points."""
        tb = self.tables
        contrast, energy = self._grids(r)
        shape = (x.size, self._cx.size)
        which = np.broadcast_to(np.arange(shape[1], dtype=np.float64), shape)
        ltr = np.broadcast_to(np.log(tr)[:, None], shape)
        ldr = np.broadcast_to(
            np.log(np.minimum(np.maximum(dr, tb.c_d[0]), tb.c_d[-1]))[:, None], shape
        )
        rad = self._rad / r
        edge = np.hypot(x[:, None] - self._cx, y[:, None] - self._cy) / r - rad
        # Thicker than the last node: solved as that thick, the inclusion at its true depth.
        t_inc = np.minimum(t, tb.c_t[-1] * r)[:, None]
        top = np.minimum(self._top / t_inc, 1.0)
        bottom = np.minimum((self._top + self._height) / t_inc, 1.0)
        c0 = np.exp(contrast(which, ltr, ldr, top))
        axis = np.full(shape, tb.e_off[0])
        four = [np.stack([v] * 4) for v in (which, ltr, ldr)]
        q = energy(
            *four, np.stack([edge, edge, axis, axis]), np.stack([bottom, top, np.ones(shape), top])
        )
        held, full = q[0] - q[1], q[2] - q[3]
        with np.errstate(divide="ignore", invalid="ignore"):
            # A small cylinder by the contact's edge can hold more energy than on the axis (the
            # energy density peaks there): shares above 1 are kept, capped against noise at 2.
            share = np.where(full > 1e-12, np.clip(held / full, 0.0, 2.0), 0.0)
        share[edge > tb.e_off[-1]] = 0.0  # beyond the table: no strain energy of the indentation
        # Narrower than the first node: the excess scales with the cross-section it occupies.
        area = np.minimum(rad / tb.c_r[0], 1.0) ** 2
        out: FloatArray = (c0 - 1.0) * share * area
        return out

    def _grids(self, r: float) -> tuple[Grid, Grid]:
        """The contrast (inclusion, log t, log d, s) and energy (inclusion, log t, log d, e, z) grids
        with this world's nu and each inclusion's radius over r and stiffness ratio fixed."""
        cached = self._grid_cache.get(r)
        if cached is None:
            tb = self.tables
            contrast, energy = tb.contrast.fix(0, self.nu), tb.energy.fix(0, self.nu)
            cs, es = [], []
            for rad, k in zip(self._rad, self._ratio, strict=True):
                lrad = float(np.log(np.clip(rad / r, tb.c_r[0], tb.c_r[-1])))
                cs.append(contrast.fix(4, float(np.log(k))).fix(3, lrad))
                es.append(energy.fix(2, lrad))
            cached = (Grid.stack(cs), Grid.stack(es))
            if len(self._grid_cache) > 8:
                self._grid_cache.clear()
            self._grid_cache[r] = cached
        return cached

    def _check(self, x: FloatArray, y: FloatArray, d: FloatArray, t: FloatArray, r: float) -> None:
        tb = self.tables
        on = t > 0
        bad = on & (t / r < tb.hom_t[0])
        if bad.any():
            i = int(np.argmax(bad))
            raise WorldRangeError(
                f"world: at ({x[i]:.2f}, {y[i]:.2f}) mm the layer is {t[i]:.3g} mm thick, below the "
                f"tables' {tb.hom_t[0]} x the indenter radius {r} mm"
            )
        limit = np.minimum(MAX_DEPTH_OVER_RADIUS * r, MAX_DEPTH_OVER_THICKNESS * t)
        bad = on & (d > limit * (1 + 1e-9))
        if bad.any():
            i = int(np.argmax(bad))
            raise WorldRangeError(
                f"world: depth {d[i]:.3g} mm at ({x[i]:.2f}, {y[i]:.2f}) mm is beyond the tables: "
                f"at most min({MAX_DEPTH_OVER_RADIUS} r, {MAX_DEPTH_OVER_THICKNESS} t) = "
                f"{limit[i]:.3g} mm (r = {r} mm, local thickness t = {t[i]:.3g} mm)"
            )

    def force_n(
        self,
        x_mm: ArrayLike,
        y_mm: ArrayLike,
        depth_mm: ArrayLike,
        *,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
    ) -> ArrayLike:
        """Force (N) on a rigid frictionless sphere pressed depth_mm below the local surface.

        0 for depth <= 0 (not touching), nan off the footprint.
        """
        r = _check_radius(indenter_radius_mm)
        xa, ya, da = (
            a.ravel() for a in np.broadcast_arrays(_f64(x_mm), _f64(y_mm), _f64(depth_mm))
        )
        shape = np.broadcast_shapes(np.shape(x_mm), np.shape(y_mm), np.shape(depth_mm))
        if not np.all(np.isfinite(da)):
            raise WorldRangeError("world: depth_mm must be finite")
        out = np.zeros(xa.size)
        on = np.asarray(self.phantom.thickness(xa, ya)) > 0
        touch = on & (da > 0)
        if touch.any():
            f, c, _ = self._parts(xa[touch], ya[touch], da[touch], r)
            out[touch] = f * c
        out[~on] = np.nan
        return _out(out.reshape(shape), x_mm, y_mm, depth_mm)

    def deepest_mm(
        self, x_mm: ArrayLike, y_mm: ArrayLike, *, indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM
    ) -> ArrayLike:
        """The deepest press (mm) the tables cover at (x, y): min(r, 0.75 t); nan off the footprint.

        Deeper than this the world has no answer; a driver decides what bottoming out means.
        """
        r = _check_radius(indenter_radius_mm)
        t = np.asarray(self.phantom.thickness(_f64(x_mm), _f64(y_mm)), dtype=np.float64)
        out = np.where(t > 0, np.minimum(MAX_DEPTH_OVER_RADIUS * r, MAX_DEPTH_OVER_THICKNESS * t), np.nan)
        return _out(out, x_mm, y_mm)

    def depth_mm(
        self,
        x_mm: ArrayLike,
        y_mm: ArrayLike,
        force_n: ArrayLike,
        *,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
    ) -> ArrayLike:
        """Depth (mm) at which the sphere at (x, y) carries force_n (N): the inverse of force_n.

        0 for force <= 0, nan off the footprint; a force beyond the deepest allowed depth,
        min(r, 0.75 t), raises WorldRangeError (a driver decides what bottoming out means).
        Agrees with force_n to ~1e-9 relative (5-6 vectorised forward evaluations).
        """
        r = _check_radius(indenter_radius_mm)
        xa, ya, fa = (a.ravel() for a in np.broadcast_arrays(_f64(x_mm), _f64(y_mm), _f64(force_n)))
        shape = np.broadcast_shapes(np.shape(x_mm), np.shape(y_mm), np.shape(force_n))
        if not np.all(np.isfinite(fa)):
            raise WorldRangeError("world: force_n must be finite")
        out = np.zeros(xa.size)
        t = np.asarray(self.phantom.thickness(xa, ya), dtype=float)
        on = t > 0
        push = on & (fa > 0)
        if push.any():
            out[push] = self._invert(xa[push], ya[push], fa[push], t[push], r)
        out[~on] = np.nan
        return _out(out.reshape(shape), x_mm, y_mm, force_n)

    def _invert(
        self, x: FloatArray, y: FloatArray, f: FloatArray, t: FloatArray, r: float
    ) -> FloatArray:
        """Depths carrying forces f (all > 0) at on-footprint points.

        The homogeneous force at the local thickness is piecewise linear in log d between the
        table's nodes (that is its interpolation), so inverting it is exact; the contrast varies
        slowly with depth, so d = hom^-1(f / C(d)) converges in a few vectorised steps.
        """
        tb = self.tables
        dmax = np.minimum(MAX_DEPTH_OVER_RADIUS * r, MAX_DEPTH_OVER_THICKNESS * t)
        fm, cm, _ = self._parts(x, y, dmax, r)
        over = f > fm * cm * (1 + 1e-9)
        if over.any():
            i = int(np.argmax(over))
            raise WorldRangeError(
                f"world: force {f[i]:.4g} N at ({x[i]:.2f}, {y[i]:.2f}) mm needs a depth beyond the "
                f"tables' {dmax[i]:.3g} mm (which carries {fm[i] * cm[i]:.4g} N)"
            )
        lnodes = np.log(tb.hom_d)
        ltr = np.log(np.minimum(np.maximum(t / r, 1e-9), tb.hom_t[-1]))
        rung = self._hom(np.repeat(ltr, lnodes.size), np.tile(lnodes, x.size))
        rung = rung.reshape(x.size, lnodes.size)  # log F/(E r^2) at each node, per point
        rows = np.arange(x.size)
        scale = self.e_kpa * 1e-3 * r * r
        lmax = np.log(dmax)

        def hom_inverse(force: FloatArray) -> FloatArray:  # log depth (mm)
            target = np.log(force / scale)
            k = np.clip((rung < target[:, None]).sum(axis=1) - 1, 0, lnodes.size - 2)
            lo, hi = rung[rows, k], rung[rows, k + 1]
            ld = lnodes[k] + (target - lo) * (lnodes[k + 1] - lnodes[k]) / (hi - lo)
            hertz = lnodes[0] + (target - rung[:, 0]) / 1.5  # below the first node: F ~ d^1.5
            out: FloatArray = np.minimum(np.where(target < rung[:, 0], hertz, ld) + np.log(r), lmax)
            return out

        ld = hom_inverse(f)
        prev: tuple[FloatArray, FloatArray] | None = None
        for _ in range(0 if self._cx.size == 0 else 20):
            _, contrast, _ = self._parts(x, y, np.exp(ld), r)
            step = hom_inverse(f / contrast)
            res = step - ld
            if np.max(np.abs(res)) < 1e-11:
                ld = step
                break
            new = step
            if prev is not None:  # secant on the fixed point ld = step(ld)
                den = res - prev[1]
                ok = np.abs(den) > 1e-14
                new = np.where(ok, ld - res * (ld - prev[0]) / np.where(ok, den, 1.0), step)
            prev = (ld, res)
            ld = np.minimum(new, lmax)
        d: FloatArray = np.exp(ld)
        return d

    # ------------------------------------------------------------------ for people

    def explain(
        self,
        x_mm: float,
        y_mm: float,
        depth_mm: float,
        *,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
    ) -> dict[str, Any]:
        """One point's force with its context: thickness, materials, each inclusion's share."""
        r = _check_radius(indenter_radius_mm)
        force = float(self.force_n(x_mm, y_mm, depth_mm, indenter_radius_mm=r))
        t = float(self.phantom.thickness(x_mm, y_mm))
        info: dict[str, Any] = {
            "force_n": force,
            "x_mm": x_mm,
            "y_mm": y_mm,
            "depth_mm": depth_mm,
            "indenter_radius_mm": r,
            "thickness_mm": t,
            "poisson_ratio": self.nu,
            "background_kpa": self.e_kpa,
        }
        if t <= 0:
            return info | {"note": "off the phantom's footprint"}
        idx = int(self.phantom.inclusion_at(x_mm, y_mm))
        info["inclusion_under_point"] = idx if idx >= 0 else None
        if depth_mm > 0:
            pt = np.array([float(x_mm)]), np.array([float(y_mm)])
            f0, c, ex = self._parts(pt[0], pt[1], np.array([float(depth_mm)]), r)
            info["homogeneous_force_n"] = float(f0[0])
            info["contrast"] = float(c[0])
            info["inclusions"] = [
                {
                    "index": i,
                    "offset_mm": round(float(np.hypot(x_mm - self._cx[i], y_mm - self._cy[i])), 4),
                    "excess": float(ex[0, i]),
                }
                for i in range(self._cx.size)
                if abs(ex[0, i]) > 1e-4
            ]
        return info
