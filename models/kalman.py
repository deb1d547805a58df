"""One-dimensional Kalman filters for the marker centroids (paper 2, Algorithm 1, lines 12-18).

Each marker's image x coordinate is modelled as a random walk observed directly:

    predict:  x⁻ = x,            p⁻ = p + q
    update:   k = p⁻ / (p⁻ + r), x = x⁻ + k (z − x⁻),   p = (1 − k) p⁻

Algorithm 1 literally writes ``p⁻_i = p⁻_{i-1} + q`` (the *prior* of the previous step);
taken literally the variance never shrinks and the gain tends to 1, i.e. no filtering.
We use the standard recursion on the *posterior* p, which is what the paper's tuning
(q = 0.09, r = 4, p0 = 6, all in px²) implies: a steady-state gain of about 0.139.

The bank is vectorised over markers (numpy arrays of shape (n,)) and updated in place.
A marker without a measurement this frame (lost / occluded) takes the prediction only:
its estimate stays where it was and its variance grows by q per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "KalmanParams",
    "ScalarKalmanBank",
    "steady_state_gain",
    "steady_state_variance",
]


@dataclass(frozen=True, slots=True)
class KalmanParams:
    """Noise parameters of the random-walk filter, all in px² (variances of the image x).

    q: process noise added per frame; r: measurement noise; p0: initial variance.
    Defaults are the paper's empirically chosen q0 = 0.09, r0 = 4, p0 = 6.
    """

    q: float = 0.09
    r: float = 4.0
    p0: float = 6.0

    def __post_init__(self) -> None:
        for name in ("q", "r", "p0"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"KalmanParams.{name}: expected a finite number >= 0, got {value!r}")
        if self.r == 0.0 and self.q == 0.0:
            raise ValueError("KalmanParams: q and r cannot both be 0 (the gain is undefined)")


def steady_state_variance(q: float, r: float) -> tuple[float, float]:
    """Steady-state (prior, posterior) variances in px² of the random-walk filter.

    The prior satisfies p⁻² − q p⁻ − q r = 0, so p⁻ = (q + √(q² + 4 q r)) / 2 and the
    posterior is p⁻ r / (p⁻ + r). For the paper's q = 0.09, r = 4: (0.647, 0.557).
    """
    if q < 0.0 or r < 0.0 or (q == 0.0 and r == 0.0):
        raise ValueError(f"steady_state_variance: need q >= 0, r >= 0, not both 0; got q={q}, r={r}")
    prior = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r))
    posterior = prior * r / (prior + r) if prior + r > 0.0 else 0.0
    return prior, posterior


def steady_state_gain(q: float = 0.09, r: float = 4.0) -> float:
    """Steady-state Kalman gain k∞ = p⁻∞ / (p⁻∞ + r) (dimensionless, 0..1).

    About 0.139 for the paper's q = 0.09, r = 4: a step in the measured centroid is
    followed with a time constant of about 1/k∞ ≈ 7 frames (0.24 s at 30 fps).
    """
    prior, _ = steady_state_variance(q, r)
    return prior / (prior + r)


class ScalarKalmanBank:
    """n independent scalar random-walk Kalman filters, stepped together.

    ``x`` (estimates, px) and ``p`` (variances, px²) are public read-only views of the
    state; ``initialized`` marks the filters that have received their first measurement.
    A filter that is not initialised ignores predict steps and is initialised (x = z,
    p = p0) by its first valid measurement.
    """

    def __init__(self, n: int, params: KalmanParams | None = None) -> None:
        if n < 1:
            raise ValueError(f"ScalarKalmanBank: n must be >= 1, got {n}")
        self.params = params if params is not None else KalmanParams()
        self.n = n
        self._x = np.zeros(n)
        self._p = np.full(n, self.params.p0)
        self._init = np.zeros(n, dtype=bool)
        self._k = np.zeros(n)
        self._x_view, self._p_view = _readonly(self._x), _readonly(self._p)
        self._k_view, self._init_view = _readonly(self._k), _readonly(self._init)

    @property
    def x(self) -> FloatArray:
        """Current estimates (px), shape (n,), a read-only view of the live state; 0 where not initialised."""
        return self._x_view

    @property
    def p(self) -> FloatArray:
        """Current posterior variances (px²), shape (n,), read-only view."""
        return self._p_view

    @property
    def gain(self) -> FloatArray:
        """Gain used by the last update (0 for filters that were not updated), shape (n,), read-only view."""
        return self._k_view

    @property
    def initialized(self) -> BoolArray:
        """Which filters hold an estimate, shape (n,), read-only view."""
        return self._init_view

    def reset(self, x0: npt.ArrayLike | None = None, mask: npt.ArrayLike | None = None) -> None:
        """(Re)initialise filters: x = x0, p = p0 where ``mask`` (default: all).

        With ``x0`` None the selected filters are marked uninitialised instead.
        """
        sel = self._mask(mask)
        if x0 is None:
            self._init[sel] = False
            self._x[sel] = 0.0
        else:
            xv = np.broadcast_to(np.asarray(x0, dtype=np.float64), (self.n,))
            if not np.all(np.isfinite(xv[sel])):
                raise ValueError(f"ScalarKalmanBank.reset: x0 must be finite where selected, got {xv}")
            self._x[sel] = xv[sel]
            self._init[sel] = True
        self._p[sel] = self.params.p0

    def predict(self, mask: npt.ArrayLike | None = None) -> None:
        """Prediction step (x unchanged, p += q) for the initialised filters in ``mask``."""
        sel = self._init if mask is None else self._mask(mask) & self._init
        np.add(self._p, self.params.q, out=self._p, where=sel)

    def update(self, z: npt.ArrayLike, valid: npt.ArrayLike | None = None) -> None:
        """Measurement update with z (px) where ``valid``; uninitialised filters take x = z, p = p0."""
        zv = np.asarray(z, dtype=np.float64)
        if zv.shape != (self.n,):
            raise ValueError(f"ScalarKalmanBank.update: z must have shape ({self.n},), got {zv.shape}")
        sel = np.isfinite(zv)
        if valid is not None:
            sel &= self._mask(valid)
        # Whole-array arithmetic (gain 0 where not updated) instead of fancy indexing: a few
        # microseconds for the four markers, every frame.
        zf = np.where(sel, zv, self._x)
        k = self._k
        if self.params.r == 0.0:
            k.fill(1.0)
        else:
            np.divide(self._p, self._p + self.params.r, out=k)
        k *= sel & self._init
        self._x += k * (zf - self._x)
        self._p *= 1.0 - k
        fresh = sel & ~self._init
        if fresh.any():
            self._x[fresh] = zf[fresh]
            self._p[fresh] = self.params.p0
            self._init |= fresh

    def step(self, z: npt.ArrayLike, valid: npt.ArrayLike | None = None) -> FloatArray:
        """One frame: predict every initialised filter, update those with a valid z.

        Filters whose ``valid`` entry is False (or whose z is NaN) are predict-only.
        Returns the estimates (px) as a read-only view of the live state (copy it to keep it).
        """
        self.predict()
        self.update(z, valid)
        return self._x_view

    def _mask(self, mask: npt.ArrayLike | None) -> BoolArray:
        if mask is None:
            return np.ones(self.n, dtype=bool)
        m = np.asarray(mask, dtype=bool)
        if m.shape != (self.n,):
            raise ValueError(f"ScalarKalmanBank: mask must have shape ({self.n},), got {m.shape}")
        return m


def _readonly(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    view = a.view()
    view.flags.writeable = False
    return view
