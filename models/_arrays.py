"""Array conventions shared by the vectorised models: accept floats or numpy arrays, return a float when every
input was a scalar (so scalar callers get plain floats), else the broadcast array."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["ArrayLike", "FloatArray", "as_f64", "scalar_or_array"]

FloatArray = npt.NDArray[np.float64]
ArrayLike = float | FloatArray


def as_f64(x: ArrayLike) -> FloatArray:
    """``x`` as a float64 array (no copy when it already is one)."""
    return np.asarray(x, dtype=np.float64)


def scalar_or_array(value: FloatArray, *inputs: object) -> ArrayLike:
    """A Python float when every input was a scalar, else the array."""
    for a in inputs:
        # plain Python numbers first: the scalar callers of the hot paths pass them, and np.ndim costs ~1 us each
        if type(a) is not float and type(a) is not int and np.ndim(a) != 0:  # type: ignore[arg-type]
            return value
    return float(value)
