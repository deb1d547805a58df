"""Simulated fibre-optic DAQ: the four sensor heights computed from the phantom, the robot pose and the probe
pressure, through the same models the estimator inverts (plus sensor noise and stroke limits).

Implements :class:`nodes.drivers.fibre.FibreDriver`; the node feeds it the latest pose and pressure from the bus.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from models.airfloat import (
    DEFAULT_INDENTER_RADIUS_MM,
    DEFAULT_SPS_RADIUS_MM,
    ForceCalibration,
    heights_over_phantom,
)
from models.contact import corrected_depth
from models.phantom import Phantom
from models.timeseries import StampedBuffer
from nodes.drivers.fibre import FibreCounters, FibreSample, FibreStatus

__all__ = ["SimFibreDriver"]

_POSE_WAIT_NS = 50_000_000
_POSE_HOLD_NS = 1_000_000_000


class SimFibreDriver:
    """Heights h1..h4 (mm) at ``rate_hz`` of simulated time, generated lazily up to the clock's now."""

    def __init__(
        self,
        phantom: Phantom,
        clock: Callable[[], int],
        *,
        rate_hz: float = 500.0,
        sps_radius_mm: float = DEFAULT_SPS_RADIUS_MM,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
        stroke_mm: float = 10.0,
        noise_mm: float | None = None,
        calibration: ForceCalibration | None = None,
        seed: int = 0,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.phantom = phantom
        self._clock = clock
        self._period_ns = int(1e9 / rate_hz)
        self._a = sps_radius_mm
        self._r = indenter_radius_mm
        self._stroke = stroke_mm
        self._noise = phantom.noise.displacement_mm if noise_mm is None else noise_mm
        self._cal = calibration or ForceCalibration()
        self._rng = np.random.default_rng(seed)
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._pressure = StampedBuffer(max_gap_ns=500_000_000)
        self._next_ns: int | None = None
        self._seq = 0
        self._samples = 0
        self._open = False
        self._e_guess: float | None = None

    # inputs from the bus
    def set_pose(self, stamp_ns: int, x_mm: float, y_mm: float, z_mm: float) -> None:
        self._pose.add(stamp_ns, (x_mm, y_mm, z_mm))

    def set_pressure(self, stamp_ns: int, kpa: float) -> None:
        self._pressure.add(stamp_ns, (kpa,))

    # FibreDriver
    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False

    def set_rate(self, hz: float) -> None:
        self._period_ns = int(1e9 / hz)

    def zero(self) -> None:
        """Nothing to tare: the simulated sensors have no offset."""

    def status(self) -> FibreStatus:
        return FibreStatus(
            connected=self._open and len(self._pose) > 0,
            last_error=None if len(self._pose) else "waiting for robot/pose",
            counters=FibreCounters(samples=self._samples),
            clock_offset_ns=0,
            rate_hz=1e9 / self._period_ns,
            port="sim",
        )

    def read(self, timeout_s: float = 0.0) -> list[FibreSample]:
        """Every sample due between the previous call and now (needs a pose; pressure defaults to 0)."""
        latest_pose = self._pose.latest_stamp
        if not self._open or latest_pose is None:
            return []
        now = self._clock()
        if self._next_ns is None:
            self._next_ns = now
        # wait up to 50 ms for poses so that motion is interpolated, not guessed; past that the sensor streams
        # on at the last known pose (a real DAQ does not wait for the robot; a stalled pose stream must not
        # look like a dead sensor)
        end = now if now - latest_pose > _POSE_WAIT_NS else min(now, latest_pose)
        if end < self._next_ns:
            return []
        stamps = np.arange(self._next_ns, end + 1, self._period_ns, dtype=np.int64)
        self._next_ns = int(stamps[-1]) + self._period_ns
        poses: list[tuple[float, ...]] = []
        keep: list[int] = []
        for t in stamps.tolist():
            p = self._pose.at(t, max_extrapolate_ns=_POSE_HOLD_NS)
            if p is not None:
                poses.append(p)
                keep.append(t)
        if not keep:
            return []
        xyz = np.asarray(poses)
        pressure = np.array([(self._pressure.at(t, 500_000_000) or (0.0,))[0] for t in keep])
        heights = self._heights(xyz[:, 0], xyz[:, 1], xyz[:, 2], pressure)
        out = []
        for t, (h1, h2, h3, h4) in zip(keep, heights.tolist(), strict=True):
            self._seq += 1
            hs = (h1, h2, h3, h4)
            out.append(FibreSample(host_stamp_ns=t, device_stamp_ns=t, seq=self._seq, raw=hs, heights_mm=hs,
                                   stamp_ns=t))
        self._samples += len(out)
        return out

    def _heights(self, x: np.ndarray, y: np.ndarray, z_face: np.ndarray, pressure_kpa: np.ndarray) -> np.ndarray:
        ph = self.phantom
        force = np.asarray(self._cal.force_n(pressure_kpa), dtype=float)
        thickness = np.asarray(ph.thickness(x, y), dtype=float)
        inside = np.isfinite(thickness) & (thickness > 0)
        gap = z_face - np.where(inside, thickness, 0.0)
        depth = np.zeros_like(x)
        touch = inside & (force > 0) & (gap < self._stroke)
        if np.any(touch):
            # the felt modulus depends on how deep the indenter goes: a fixed point, warm-started from the
            # previous batch (the probe moves little between batches), so two rounds converge
            e = np.full(int(touch.sum()), self._e_guess or float(ph.youngs_modulus_kpa or 0.0))
            for _ in range(2):
                d = np.asarray(corrected_depth(force[touch], e, self._r, thickness[touch], ph.poisson_ratio))
                e = np.asarray(ph.effective_modulus(x[touch], y[touch], self._r, d), dtype=float)
            d = np.asarray(corrected_depth(force[touch], e, self._r, thickness[touch], ph.poisson_ratio))
            self._e_guess = float(e[-1])
            depth[touch] = d
        xs, ys = np.where(inside, x, np.clip(x, 0, ph.size_mm[0])), np.where(inside, y, np.clip(y, 0, ph.size_mm[1]))
        h = np.stack(heights_over_phantom(ph, xs, ys, z_face, depth, self._a, self._r), axis=-1)
        h = np.where(np.isfinite(h), h, self._stroke)
        if self._noise > 0:
            h = h + self._rng.normal(0.0, self._noise, h.shape)
        out: np.ndarray = np.clip(h, 0.0, self._stroke)
        return out
