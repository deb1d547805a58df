"""The three grid operations the map detector needs from ``scipy.ndimage``, in numpy, with the same results to the bit.

A composed simulation imports the detector's code at start-up, and ``scipy.ndimage`` alone takes ~0.16 s to
import (scipy's array-API layer, mostly), on the critical path of every ``palpa launch --in-process``. The
detector uses only a sum over a disc of 0/1 weights (``ndimage.convolve(..., mode="constant")``), 8-connected
labelling (``ndimage.label`` with a 3×3 structure) and a binary dilation by a symmetric structure; on the small
grids of a stiffness map these take a few numpy calls each.

Each equals its ``scipy.ndimage`` counterpart exactly (tests/test_grid_filters.py compares them on random grids):
:func:`disc_sum` adds the taps in the order ``ndimage`` does (the kernel's cells in C order, from 0.0), so even
the floating-point rounding is the same.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from models._arrays import FloatArray

__all__ = ["dilate", "disc_sum", "label8"]

BoolArray = npt.NDArray[np.bool_]


def _check_kernel(kernel: np.ndarray) -> tuple[int, int]:
    kh, kw = kernel.shape
    if kh % 2 == 0 or kw % 2 == 0:
        raise ValueError(f"grid_filters: a kernel of odd sides is needed (its centre is a cell), got {kernel.shape}")
    if not np.array_equal(kernel, kernel[::-1, ::-1]):
        raise ValueError("grid_filters: the kernel must be symmetric under a half turn (convolution = correlation)")
    return kh // 2, kw // 2


def disc_sum(values: FloatArray, kernel: FloatArray) -> FloatArray:
    """``scipy.ndimage.convolve(values, kernel, mode="constant", cval=0.0)`` for a 2-D kernel of 0/1 weights with
    odd sides, symmetric under a half turn (a disc): each cell's sum of the values under the kernel, outside the
    grid counting 0, added in the kernel's C order starting from 0.0 as ``ndimage`` adds them."""
    grid = np.asarray(values, dtype=np.float64)
    weights = np.asarray(kernel, dtype=np.float64)
    if grid.ndim != 2 or weights.ndim != 2:
        raise ValueError("disc_sum: a 2-D grid and a 2-D kernel are needed")
    gather, (ry, rx) = _taps(grid.shape, weights.shape, weights.tobytes())
    ny, nx = grid.shape
    padded = np.zeros((ny + 2 * ry, nx + 2 * rx))
    padded[ry : ry + ny, rx : rx + nx] = grid
    # a reduction over the outer axis adds slice after slice (no pairwise summation): ndimage's order exactly
    out: FloatArray = np.add.reduce(padded.ravel()[gather], axis=0, initial=0.0).reshape(ny, nx)
    return out


@functools.lru_cache(maxsize=16)  # a map keeps its shape: 4 radii x a few shapes (~0.3 MB each at 24 x 24)
def _taps(shape: tuple[int, int], kshape: tuple[int, int], kbytes: bytes) -> tuple[np.ndarray, tuple[int, int]]:
    """For a grid of ``shape`` zero-padded by the kernel's half sides: the flat index of each kernel cell's value
    under each grid cell, (taps in the kernel's C order, cells); and the half sides."""
    weights = np.frombuffer(kbytes, dtype=np.float64).reshape(kshape)
    if not np.isin(weights, (0.0, 1.0)).all():
        raise ValueError("disc_sum: a kernel of 0/1 weights is needed")
    ry, rx = _check_kernel(weights)
    ny, nx = shape
    width = nx + 2 * rx
    cells = (np.arange(ny)[:, None] * width + np.arange(nx)[None, :]).ravel()
    dy, dx = np.nonzero(weights)  # C order
    gather = (dy * width + dx)[:, None] + cells[None, :]
    gather.setflags(write=False)
    return gather, (ry, rx)


def dilate(mask: BoolArray, structure: BoolArray) -> BoolArray:
    """``scipy.ndimage.binary_dilation(mask, structure)`` (one iteration, nothing set beyond the border) for a 2-D
    structure with odd sides, symmetric under a half turn: a cell is set if the structure centred on it covers a
    set cell."""
    s = np.asarray(structure, dtype=bool)
    if s.ndim != 2:
        raise ValueError("dilate: a 2-D structure is needed")
    ry, rx = _check_kernel(s)
    padded = np.pad(np.asarray(mask, dtype=bool), ((ry, ry), (rx, rx)))
    windows = sliding_window_view(padded, s.shape)
    out: BoolArray = np.asarray(windows[..., s].any(axis=-1), dtype=bool)
    return out


def label8(mask: BoolArray) -> tuple[np.ndarray, int]:
    """``scipy.ndimage.label(mask, structure=np.ones((3, 3)))``: the 8-connected regions of a 2-D mask numbered
    1..n in the order their first cell comes in C order (0 off the mask), and n.

    Every cell of the mask starts as its own flat index; each round takes the least index among itself and its 8
    neighbours, then follows the links to their ends (pointer jumping), until the region's cells agree on its least
    index, its first cell: a few rounds even for a long winding region (tests/test_grid_filters.py's spiral)."""
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError("label8: a 2-D mask is needed")
    ny, nx = m.shape
    big = ny * nx
    idx = np.where(m, np.arange(big, dtype=np.int64).reshape(ny, nx), big)
    padded = np.full((ny + 2, nx + 2), big, dtype=np.int64)
    inner = padded[1:-1, 1:-1]
    shifts = [padded[dy : dy + ny, dx : dx + nx] for dy in range(3) for dx in range(3) if (dy, dx) != (1, 1)]
    flat = np.empty(big + 1, dtype=np.int64)
    flat[big] = big  # off the mask links to itself
    while True:
        inner[...] = idx
        least = idx.copy()
        for s in shifts:
            np.minimum(least, s, out=least)
        least[~m] = big
        flat[:big] = least.ravel()
        while True:  # follow the links to their ends
            nxt = flat[flat]
            if np.array_equal(nxt, flat):
                break
            flat = nxt
        least = flat[:big].reshape(ny, nx).copy()
        if np.array_equal(least, idx):
            break
        idx = least
    roots = np.unique(idx[m])
    labels = np.zeros((ny, nx), dtype=np.int32)
    labels[m] = np.searchsorted(roots, idx[m]) + 1
    return labels, int(roots.size)
