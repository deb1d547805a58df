"""Simulated fibre-optic DAQ: the air-float probe as a device in the simulated world.

For each sample time it takes the robot pose and the regulator's read-back pressure (from the bus), and
1. the probe's internal pressure and the force the tissue feels come from the *device's true force law*
   (``models.airfloat_device.TrueProbe``: drawn gain/offset, bend, bore-friction hysteresis), never from the
   estimator's eq. 4 calibration;
2. the indentation depth comes from the world (``models.world.TissueWorld``: FE-grounded mechanics, never
   eq. 7; its force-depth curve per 0.5 mm cell, inverted), with the friction's play: the indenter sticks while the depth lies between the
   equilibria of F_air - f and F_air + f;
3. the four extensions come from the true surface geometry (each SPS tip over the real dome under it, floating
   on its air gap; the indenter ``depth`` below the true surface point under it, ``depth_reference="surface"``;
   a tip off the specimen over the table, z = 0);
4. the fibre channels report them through their calibration errors and noise, clipped to the stroke.

Samples fall on a grid of absolute simulated time (multiples of the period), and each one's noise is a function of
the seed and its grid index counted from the whole second of the first sample (simulated time starts on a whole
second, composed or not: the same seed then gives the same noise in every run), so what the sensor reports depends
on simulated time and the seed only, not on when or how often the node reads the driver (a composed run reads it at other instants
than a multi-process one).

Implements :class:`nodes.drivers.fibre.FibreDriver`; the node feeds it the latest pose and pressure from the bus.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from models._arrays import ArrayLike
from models.airfloat import DEFAULT_INDENTER_RADIUS_MM, DEFAULT_SPS_RADIUS_MM, heights_over_phantom
from models.airfloat_device import ProbeErrors, TrueProbe
from models.phantom import Phantom
from models.timeseries import StampedBuffer
from models.world import MAX_DEPTH_OVER_RADIUS, MAX_DEPTH_OVER_THICKNESS
from nodes.drivers.fibre import FibreCounters, FibreSample, FibreStatus

__all__ = ["IndentationWorld", "SimFibreDriver", "tissue_world"]

log = logging.getLogger(__name__)

_POSE_WAIT_NS = 1_000_000_000
"""Samples are made only as far as the arm's pose is known, for up to this long (the simulated camera's
``max_wait_ns``): a pose stream running late (a starved process on a wall clock) delays the samples instead of
showing them the arm where it was; stalled for longer, the sensor streams on (a real DAQ does not wait for the
robot)."""
_MAX_CATCHUP_NS = 2_000_000_000
"""Simulated ns of samples one read makes at most: after a longer gap (a node starved, a clock that jumped) the
older samples are skipped (counted in ``skipped``), never allocated all at once."""
_CELL_MM = 0.5  # lateral resolution of the cached force-depth curves
_LADDER = np.geomspace(0.01, 1.0, 24)  # depths, as fractions of the world's limit, of each cached curve
_POSE_HOLD_NS = 1_000_000_000


class IndentationWorld(Protocol):
    """What the driver needs of the world: the force (N) on the probe's sphere pressed depth (mm) below the surface
    at (x, y) (mm)."""

    def force_n(self, x: ArrayLike, y: ArrayLike, depth: ArrayLike, /, *,
                indenter_radius_mm: float = ...) -> ArrayLike: ...


def tissue_world(phantom: Phantom) -> IndentationWorld:
    """The FE-grounded world of ``models.world`` over a phantom."""
    from models.world import TissueWorld

    world: IndentationWorld = TissueWorld(phantom)
    return world


class SimFibreDriver:
    """Heights h1..h4 (mm) at ``rate_hz`` of simulated time, generated lazily up to the clock's now."""

    def __init__(
        self,
        phantom: Phantom,
        clock: Callable[[], int],
        *,
        errors: ProbeErrors | None = None,
        world: IndentationWorld | None = None,
        rate_hz: float = 500.0,
        sps_radius_mm: float = DEFAULT_SPS_RADIUS_MM,
        indenter_radius_mm: float = DEFAULT_INDENTER_RADIUS_MM,
        stroke_mm: float = 10.0,
        seed: int = 0,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.phantom = phantom
        self.errors = errors if errors is not None else ProbeErrors.draw(seed, noise_mm=phantom.noise.displacement_mm)
        self.probe = TrueProbe(self.errors, stroke_mm)
        self.world = world if world is not None else tissue_world(phantom)
        self._clock = clock
        self._period_ns = int(1e9 / rate_hz)
        self._a = sps_radius_mm
        self._r = indenter_radius_mm
        self._stroke = stroke_mm
        self._seed = seed
        self._noise_block: tuple[int, np.ndarray] | None = None  # (block index, its standard normals)
        self._first_index: int | None = None  # noise counts grid indices from here
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._pressure = StampedBuffer(max_gap_ns=500_000_000)
        self._next_ns: int | None = None
        self._seq = 0
        self._samples = 0
        self._open = False
        self._range_warned = False
        self._curves: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}
        self._depth = 0.0  # the indenter's last depth: bore friction makes it stick (hysteresis)
        self.skipped = 0
        """Samples never made: due more than ``_MAX_CATCHUP_NS`` before a read."""

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
        """Nothing to tare: the simulated channels' errors are gain and bow, not offsets."""

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
            self._next_ns = -(-now // self._period_ns) * self._period_ns
        # made only as far as the pose is known (motion interpolated, never a stale arm), for up to _POSE_WAIT_NS;
        # past that the sensor streams on at the last known pose (a stalled pose stream must not look like a dead
        # sensor)
        end = now if now - latest_pose > _POSE_WAIT_NS else min(now, latest_pose)
        if end < self._next_ns:
            return []
        if end - self._next_ns > _MAX_CATCHUP_NS:
            skip = (end - _MAX_CATCHUP_NS - self._next_ns) // self._period_ns
            self._next_ns += skip * self._period_ns
            self.skipped += skip
            log.warning("sim fibre: %d samples (%.1f s) due before this read skipped (at most %.0f s are made at "
                        "once); %d skipped in all", skip, skip * self._period_ns / 1e9, _MAX_CATCHUP_NS / 1e9,
                        self.skipped)
        stamps = np.arange(self._next_ns, end + 1, self._period_ns, dtype=np.int64)
        self._next_ns = int(stamps[-1]) + self._period_ns
        grid = stamps.tolist()
        at = self._pose.at_each(grid, max_extrapolate_ns=_POSE_HOLD_NS)
        keep = [t for t, p in zip(grid, at, strict=True) if p is not None]
        if not keep:
            return []
        xyz = np.asarray([p for p in at if p is not None])
        pressure = np.array([(p or (0.0,))[0] for p in self._pressure.at_each(keep, 500_000_000)])
        heights = self.heights(xyz[:, 0], xyz[:, 1], xyz[:, 2], pressure, np.asarray(keep, dtype=np.int64))
        out = []
        for t, (h1, h2, h3, h4) in zip(keep, heights.tolist(), strict=True):
            self._seq += 1
            hs = (h1, h2, h3, h4)
            out.append(FibreSample(host_stamp_ns=t, device_stamp_ns=t, seq=self._seq, raw=hs, heights_mm=hs,
                                   stamp_ns=t))
        self._samples += len(out)
        return out

    def _depths(self, x: np.ndarray, y: np.ndarray, probe_kpa: np.ndarray, touch: np.ndarray,
                gap: np.ndarray) -> np.ndarray:
        """Indentation (mm) per sample: the play operator between the extending and pushed-in equilibria."""
        depth = np.zeros_like(x)
        if not np.any(touch):
            self._depth = 0.0
            return depth
        # the indenter cannot reach past its stroke: beyond it, the face is too high to touch
        reach = np.clip(self._stroke - gap[touch], 0.0, None)
        xt, yt = x[touch], y[touch]
        shallow = self._world_depth(xt, yt, np.asarray(self.probe.tissue_force_n(probe_kpa[touch], True)), reach)
        deep = self._world_depth(xt, yt, np.asarray(self.probe.tissue_force_n(probe_kpa[touch], False)), reach)
        d = np.empty_like(shallow)
        last = self._depth
        for i in range(d.size):
            last = min(max(last, shallow[i]), deep[i])
            d[i] = last
        self._depth = last
        depth[touch] = d
        return depth

    def _world_depth(self, x: np.ndarray, y: np.ndarray, force: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """The world's depth for each force, never past the stroke.

        The world's inverse costs ~0.1 s a call, too slow for 500 samples a second, so the driver asks the world's
        forward model for the whole force-depth curve of each 0.5 mm cell the probe visits (one call for all new
        cells of a batch, ``_LADDER`` depths up to the world's limit min(r, 0.75 t)) and inverts it by log-log
        interpolation. Below the first rung and beyond the last the curve is extended as F ~ d^1.5; a press beyond
        the world's limit is logged once (the world is not trusted there).
        """
        keys = np.stack([np.round(x / _CELL_MM), np.round(y / _CELL_MM)], -1).astype(np.int64)
        cells = [tuple(k) for k in keys.tolist()]
        new = sorted({c for c in cells if c not in self._curves})
        if new:
            cx = np.array([c[0] for c in new], dtype=float) * _CELL_MM
            cy = np.array([c[1] for c in new], dtype=float) * _CELL_MM
            t = np.asarray(self.phantom.thickness(cx, cy), dtype=float)
            dmax = np.minimum(MAX_DEPTH_OVER_RADIUS * self._r, MAX_DEPTH_OVER_THICKNESS * t) * (1 - 1e-6)
            ladder = dmax[:, None] * _LADDER[None, :]
            f = np.asarray(self.world.force_n(np.repeat(cx, _LADDER.size), np.repeat(cy, _LADDER.size),
                                              ladder.ravel(), indenter_radius_mm=self._r), dtype=float)
            f = f.reshape(ladder.shape)
            if len(self._curves) > 200_000:  # a very long run: forget the oldest cells
                self._curves.clear()
            for i, c in enumerate(new):
                self._curves[c] = (np.log(ladder[i]), np.log(np.maximum(f[i], 1e-300)))
        d = np.zeros(x.size)
        forces = force.tolist()
        start = 0
        while start < len(cells):  # a run of samples in one cell: one interpolation call for all of them
            c = cells[start]
            end = start + 1
            while end < len(cells) and cells[end] == c:
                end += 1
            pressed = [i for i in range(start, end) if forces[i] > 0]
            start = end
            if not pressed:
                continue
            ld, lf = self._curves[c]
            logs = [math.log(forces[i]) for i in pressed]
            inside = np.interp(logs, lf, ld).tolist()  # element by element what a call per sample gives
            for i, lfi, mid in zip(pressed, logs, inside, strict=True):
                if lfi > lf[-1] and not self._range_warned:
                    self._range_warned = True
                    log.warning("sim probe pressed beyond the world's tables at (%.1f, %.1f) mm: %.3f N > %.3f N "
                                "at %.2f mm (depth extrapolated as F ~ d^1.5)", x[i], y[i], forces[i],
                                math.exp(lf[-1]), math.exp(ld[-1]))
                if lfi <= lf[0]:
                    d[i] = math.exp(ld[0] + (lfi - lf[0]) / 1.5)
                elif lfi >= lf[-1]:
                    d[i] = math.exp(ld[-1] + (lfi - lf[-1]) / 1.5)
                else:
                    d[i] = math.exp(mid)
        out: np.ndarray = np.minimum(d, reach)
        return out

    def _unit_noise(self, stamps: np.ndarray) -> np.ndarray:
        """(n, 4) standard normals for samples at ``stamps`` (ns): drawn per block of 1024 grid indices (from the
        whole second of the first sample) from the seed and the block's index, so a sample's noise does not depend on which samples were read before it."""
        idx = stamps // self._period_ns
        if self._first_index is None and idx.size:  # the whole second of the first sample (a run starts on one)
            self._first_index = int(stamps[0]) // 1_000_000_000 * 1_000_000_000 // self._period_ns
        idx = idx - (self._first_index or 0)
        out = np.empty((idx.size, 4))
        for i, k in enumerate(idx.tolist()):
            block, row = divmod(k, 1024)
            if self._noise_block is None or self._noise_block[0] != block:
                self._noise_block = (block, np.random.default_rng([self._seed, 1, block]).standard_normal((1024, 4)))
            out[i] = self._noise_block[1][row]
        return out

    def heights(self, x: np.ndarray, y: np.ndarray, z_face: np.ndarray, readback_kpa: np.ndarray,
                stamps: np.ndarray | None = None) -> np.ndarray:
        """(n, 4) fibre readings h1..h4 (mm) for face-centre poses (x, y, z_face) and regulator read-backs at
        ``stamps`` (ns; their noise; None: noiseless)."""
        ph = self.phantom
        probe_kpa = np.asarray(self.probe.probe_pressure_kpa(readback_kpa), dtype=float)
        thickness = np.asarray(ph.thickness(x, y), dtype=float)
        inside = np.isfinite(thickness) & (thickness > 0)
        gap = z_face - np.where(inside, thickness, 0.0)
        touch = inside & (probe_kpa > 0) & (gap < self._stroke)
        depth = self._depths(x, y, probe_kpa, touch, gap)
        h = np.stack(heights_over_phantom(ph, x, y, z_face, depth, self._a, self._r, depth_reference="surface"),
                     axis=-1)
        # a tip with no specimen under it reaches for the table (z = 0) under the vertical probe, if within its stroke
        h = np.where(np.isfinite(h), h, z_face[:, None])
        h[:, :3] -= self.probe.sps_gap_mm(probe_kpa)  # each SPS tip floats above the tissue on its air cushion
        h = self.probe.fibre_readings_mm(h)
        if stamps is not None and self.errors.noise_mm > 0:
            h = h + self.errors.noise_mm * self._unit_noise(stamps)
        h = np.where(np.isfinite(h), h, self._stroke)
        out: np.ndarray = np.clip(h, 0.0, self._stroke)
        return out
