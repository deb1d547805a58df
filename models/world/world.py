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
        self._grid_cache: dict[float, list[tuple[Grid, Grid]]] = {}

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
        out = np.zeros((x.size, self._cx.size))
        ltr = np.log(tr)
        ldr = np.log(np.clip(dr, tb.c_d[0], tb.c_d[-1]))
        for j, (contrast, energy) in enumerate(self._grids(r)):
            rad = self._rad[j] / r
            off = np.hypot(x - self._cx[j], y - self._cy[j]) / r
            near = off - rad < tb.e_off[-1]  # beyond: no strain energy of the indentation there
            if not near.any():
                continue
            tn, dn, en = ltr[near], ldr[near], off[near] - rad
            top = np.clip(self._top[j] / t[near], 0.0, 1.0)
            bottom = np.clip((self._top[j] + self._height[j]) / t[near], 0.0, 1.0)
            c0 = np.exp(contrast(tn, dn, top))
            axis = np.full_like(en, tb.e_off[0])
            q = energy(
                np.tile(tn, 4), np.tile(dn, 4),
                np.concatenate([en, en, axis, axis]),
                np.concatenate([bottom, top, np.ones_like(top), top]),
            ).reshape(4, -1)  # fmt: skip
            held, full = q[0] - q[1], q[2] - q[3]
            with np.errstate(divide="ignore", invalid="ignore"):
                share = np.where(full > 1e-12, np.clip(held / full, 0.0, 1.0), 0.0)
            # Narrower than the first node: the excess scales with the cross-section it occupies.
            area = min(rad / tb.c_r[0], 1.0) ** 2
            out[near, j] = (c0 - 1.0) * share * area
        return out

    def _grids(self, r: float) -> list[tuple[Grid, Grid]]:
        """Per inclusion, the contrast (log t, log d, s) and energy (log t, log d, e, z) grids with
        this world's nu, the inclusion's radius over r and its stiffness ratio fixed (cached per r)."""
        cached = self._grid_cache.get(r)
        if cached is None:
            tb = self.tables
            contrast, energy = tb.contrast.fix(0, self.nu), tb.energy.fix(0, self.nu)
            cached = []
            for rad, k in zip(self._rad, self._ratio, strict=True):
                lrad = float(np.log(np.clip(rad / r, tb.c_r[0], tb.c_r[-1])))
                cached.append((contrast.fix(4, float(np.log(k))).fix(3, lrad), energy.fix(2, lrad)))
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

    def depth_mm(
        self,
        x_mm: ArrayLike,
        y_mm: ArrayLike,
        force_n: ArrayLike,
        *,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
    ) -> ArrayLike:
        """Depth (mm) at which the sphere at (x, y) carries force_n (N): the inverse of force_n.

        0 for force <= 0, nan off the footprint; a force beyond the deepest tabulated depth raises
        WorldRangeError. Monotonic: bracketed on a geometric depth ladder, then refined by
        interpolation in log force - log depth against the forward model itself.
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
        n = x.size
        dmax = np.minimum(MAX_DEPTH_OVER_RADIUS * r, MAX_DEPTH_OVER_THICKNESS * t)
        ladder = dmax[:, None] * np.geomspace(1e-3, 1.0, 16)[None, :]
        xs, ys = (np.repeat(v, ladder.shape[1]) for v in (x, y))
        fl, cl, _ = self._parts(xs, ys, ladder.ravel(), r)
        fl = (fl * cl).reshape(ladder.shape)
        over = f > fl[:, -1] * (1 + 1e-9)
        if over.any():
            i = int(np.argmax(over))
            raise WorldRangeError(
                f"world: force {f[i]:.4g} N at ({x[i]:.2f}, {y[i]:.2f}) mm needs a depth beyond the "
                f"tables' {dmax[i]:.3g} mm (which carries {fl[i, -1]:.4g} N)"
            )
        k = np.clip((fl < f[:, None]).sum(axis=1) - 1, 0, ladder.shape[1] - 2)
        rows = np.arange(n)
        lo_d, hi_d = np.log(ladder[rows, k]), np.log(ladder[rows, k + 1])
        lo_f, hi_f = np.log(fl[rows, k]), np.log(fl[rows, k + 1])
        lf = np.log(f)
        tiny = f < fl[:, 0]  # below the ladder's first rung: Hertz's d^1.5
        for _ in range(4):  # regula falsi in log-log, bracket kept
            ld = lo_d + (lf - lo_f) * (hi_d - lo_d) / np.maximum(hi_f - lo_f, 1e-12)
            ld = np.clip(ld, lo_d, hi_d)
            fm, cm, _ = self._parts(x, y, np.exp(ld), r)
            lm = np.log(fm * cm)
            below = lm < lf
            lo_d, lo_f = np.where(below, ld, lo_d), np.where(below, lm, lo_f)
            hi_d, hi_f = np.where(below, hi_d, ld), np.where(below, hi_f, lm)
        ld = lo_d + (lf - lo_f) * (hi_d - lo_d) / np.maximum(hi_f - lo_f, 1e-12)
        d = np.exp(np.clip(ld, lo_d, hi_d))
        d0 = ladder[:, 0] * (f / fl[:, 0]) ** (2.0 / 3.0)
        res: FloatArray = np.where(tiny, d0, d)
        return res

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
