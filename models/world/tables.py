"""The shipped finite-element tables and a fast clamped multilinear interpolation over them."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
TABLE_PATH = Path(__file__).with_name("tables.npz")


class Grid:
    """Multilinear interpolation on a regular (non-uniform) grid, inputs clamped to its box.

    All 2^n corners are gathered in one fancy-indexing step, so a call costs a few tens of numpy
    operations whatever the number of points.
    """

    def __init__(self, axes: tuple[FloatArray, ...], values: FloatArray) -> None:
        if values.shape != tuple(a.size for a in axes):
            raise ValueError(
                f"grid values {values.shape} do not match axes {[a.size for a in axes]}"
            )
        self.axes = axes
        self.lo = np.array([a[0] for a in axes])
        self.hi = np.array([a[-1] for a in axes])
        self._flat = np.ascontiguousarray(values, dtype=np.float64).ravel()
        strides = np.array([int(np.prod(values.shape[k + 1 :])) for k in range(len(axes))])
        bits = (np.arange(2 ** len(axes))[:, None] >> np.arange(len(axes))[::-1]) & 1
        self._bits = bits.T.astype(bool)  # (ndim, corners)
        self._offsets = bits @ strides
        self._strides = strides

    @property
    def values(self) -> FloatArray:
        """The node values, shaped like the axes."""
        out: FloatArray = self._flat.reshape([a.size for a in self.axes])
        return out

    @classmethod
    def stack(cls, grids: list[Grid]) -> Grid:
        """Grids on the same axes stacked along a new leading axis indexed 0, 1, ... (integers)."""
        vals = [g.values for g in grids]
        if len(vals) == 1:  # an axis needs two nodes; the copy is never weighted
            vals.append(vals[0])
        return cls((np.arange(len(vals), dtype=np.float64), *grids[0].axes), np.stack(vals))

    def fix(self, axis: int, value: float) -> Grid:
        """The grid with one axis interpolated at a constant value (clamped) and removed."""
        ax = self.axes[axis]
        v = float(np.clip(value, ax[0], ax[-1]))
        i = int(np.clip(np.searchsorted(ax, v, side="right") - 1, 0, ax.size - 2))
        f = (v - ax[i]) / (ax[i + 1] - ax[i])
        vals = self.values
        lo, hi = np.take(vals, i, axis=axis), np.take(vals, i + 1, axis=axis)
        return Grid(self.axes[:axis] + self.axes[axis + 1 :], (1.0 - f) * lo + f * hi)

    def __call__(self, *coords: FloatArray) -> FloatArray:
        """Values at points given as one broadcastable array per axis."""
        cs = np.broadcast_arrays(*coords)
        shape = cs[0].shape
        base = np.zeros(cs[0].size, dtype=np.int64)
        weight = np.ones((cs[0].size, self._offsets.size))
        for k, (ax, c) in enumerate(zip(self.axes, cs, strict=True)):
            c = np.minimum(np.maximum(c.ravel(), ax[0]), ax[-1])  # np.clip is slow on small arrays
            i = np.minimum(np.searchsorted(ax, c, side="right") - 1, ax.size - 2)
            f = (c - ax[i]) / (ax[i + 1] - ax[i])
            base += i * self._strides[k]
            weight *= np.where(self._bits[k], f[:, None], 1.0 - f[:, None])
        vals = self._flat[base[:, None] + self._offsets]
        out: FloatArray = np.einsum("ij,ij->i", weight, vals).reshape(shape)
        return out


@dataclass(frozen=True)
class Tables:
    """The three dimensionless tables (see ``models.world.build_tables``) ready to interpolate.

    Axes are transformed so that linear interpolation follows the physics: log of thickness, depth,
    inclusion radius and stiffness ratio; log of the force (Hertz's F ~ d^1.5 is linear there).
    """

    hom: Grid  # (nu, log t, log d) -> log F/(E r^2)
    contrast: Grid  # (nu, log t, log d, s, log R, log k) -> log contrast
    energy: Grid  # (nu, log t, log d, log R, e, z) -> strain-energy fraction
    hom_nu: FloatArray
    hom_t: FloatArray
    hom_d: FloatArray
    c_nu: FloatArray
    c_t: FloatArray
    c_d: FloatArray
    c_r: FloatArray
    c_k: FloatArray
    e_off: FloatArray


def tables_from_arrays(z: dict[str, FloatArray]) -> Tables:
    """Wrap the arrays of a tables.npz (as written by build_tables) in interpolation grids."""
    lg = np.log
    return Tables(
        hom=Grid((z["hom_nu"], lg(z["hom_t"]), lg(z["hom_d"])), lg(z["hom_force"])),
        contrast=Grid(
            (z["c_nu"], lg(z["c_t"]), lg(z["c_d"]), z["c_s"], lg(z["c_r"]), lg(z["c_k"])),
            lg(z["contrast"]),
        ),
        energy=Grid(
            (z["c_nu"], lg(z["c_t"]), lg(z["c_d"]), lg(z["c_r"]), z["e_off"], z["e_z"]),
            z["energy"].astype(np.float64),
        ),
        hom_nu=z["hom_nu"],
        hom_t=z["hom_t"],
        hom_d=z["hom_d"],
        c_nu=z["c_nu"],
        c_t=z["c_t"],
        c_d=z["c_d"],
        c_r=z["c_r"],
        c_k=z["c_k"],
        e_off=z["e_off"],
    )


@lru_cache(maxsize=4)
def load_tables(path: Path = TABLE_PATH) -> Tables:
    """The tables shipped next to this module (read once per process)."""
    with np.load(path) as z:
        return tables_from_arrays({k: np.asarray(z[k], dtype=np.float64) for k in z.files})
