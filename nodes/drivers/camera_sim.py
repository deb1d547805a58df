"""Simulated probe camera: frames of the four spheres rendered from the robot pose and the camera world.

The probe's reference point (the pose on ``robot/pose``) is the tip of the central, hard indenter at rest; the
probe axis is the phantom's −z (the probe presses down). Tip i sits at (x + x_i, y + y_i); the sample's free
surface under it is ``phantom.surface_z`` there, inclined by ``pan`` (slope along the probe's x) and ``tilt``
(along y), the convention of models.multi_indenter (a positive angle: the surface recedes towards +x / +y). The
overlap of tip i (how far below the free surface it would sit at rest) goes to ``models.camera_world``, which
solves the springs, friction, stroke ends and the sample (spring rods, or tissue from the FE world with the
tips coupled through the layer) for each indenter's displacement; ``models.camera_render`` draws the spheres
with the probe's own per-marker scale and lens distortion. The probe as built (its errors) is drawn from
``seed`` unless ``errors`` is None (the ideal probe, for unit tests); ``build`` holds it for the run's record.

Implements :class:`nodes.drivers.camera.FrameSource`; the node feeds it poses from the bus.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from models.camera_render import CameraModel, Renderer
from models.camera_world import (
    DEFAULT_ERRORS,
    CameraWorld,
    ProbeBuild,
    ProbeErrorSpec,
    SpringRods,
    TipForce,
    TissueTips,
)
from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry
from models.phantom import Phantom
from models.timeseries import StampedBuffer
from models.world import MAX_DEPTH_OVER_RADIUS, MAX_DEPTH_OVER_THICKNESS, TissueWorld
from nodes.drivers.camera import Frame, SimSource, SourceInfo

__all__ = ["SimCameraSource", "SimTruth"]

FloatArray = npt.NDArray[np.float64]


class _Beyond:
    """The FE world's force, continued past its tables' depth: deeper than the tip's radius its cylindrical
    shank is in contact and the force grows at the slope there (a flat punch of radius r has the incremental
    stiffness 2 r E* of a sphere whose contact radius has reached r); the same past 0.75 of the thickness."""

    def __init__(self, world: TipForce, phantom: Phantom, depth_limit: Any) -> None:
        self.world, self.phantom, self.limit = world, phantom, depth_limit

    def force_n(self, x_mm: Any, y_mm: Any, depth_mm: Any, *, indenter_radius_mm: float = 2.0) -> Any:
        x, y = x_mm, y_mm
        d = np.asarray(depth_mm, dtype=np.float64)
        lim = np.asarray(self.limit(indenter_radius_mm, self.phantom.thickness(x, y)), dtype=np.float64)
        lim = lim * (1.0 - 1e-6)
        h = 1e-3 * indenter_radius_mm
        f = self.world.force_n(x, y, np.minimum(d, lim), indenter_radius_mm=indenter_radius_mm)
        deep = d > lim
        if not np.any(deep):
            return f
        f_lim = self.world.force_n(x, y, lim, indenter_radius_mm=indenter_radius_mm)
        slope = (f_lim - np.asarray(self.world.force_n(x, y, lim - h, indenter_radius_mm=indenter_radius_mm))) / h
        return np.where(deep, f_lim + slope * (d - lim), f)


def tissue_force(phantom: Phantom) -> TipForce:
    """The FE tissue world for the camera probe's tips, continued past its tables' depth."""
    return _Beyond(TissueWorld(phantom), phantom, lambda r, t: np.minimum(
        MAX_DEPTH_OVER_RADIUS * r, MAX_DEPTH_OVER_THICKNESS * np.asarray(t)))


@dataclass(frozen=True)
class SimTruth:
    """What the last rendered frame shows: the truth a tracker and an estimator are judged against.

    stamp_ns; advance_mm of the probe past its first tip's contact (<= 0: not touching); k_t_n_per_mm: the
    sample's spring constant at the probe centre (spring samples; NaN for tissue: there is no single K_t);
    displacement_mm of each indenter; contact flags; force_n on each tip; centres_px drawn (jitter included).
    """

    stamp_ns: int
    advance_mm: float
    k_t_n_per_mm: float
    displacement_mm: FloatArray
    contact: npt.NDArray[np.bool_]
    centres_px: FloatArray
    force_n: FloatArray


class SimCameraSource:
    """A :class:`~nodes.drivers.camera.FrameSource` rendering the probe camera at ``rate_hz`` of ``clock``.

    ``pan_deg``/``tilt_deg``: the sample surface's inclination relative to the probe (degrees, < 90);
    ``camera``: the image model (its ``jitter_px`` is replaced by ``pixel_noise_px`` when given, else by the
    phantom's ``noise.pixel``; its scale and distortion by the probe's as built). ``geometry``: the nominal
    probe; ``errors``: the manufacturing/camera error ranges the probe is drawn from with ``device_seed`` (None:
    the ideal probe); ``seed``: the image noise. ``occluded`` (settable, bool per marker) hides spheres, for lost-marker tests. Before any pose
    arrives the probe is off the sample (spheres at rest); afterwards the pose at each frame's stamp is
    interpolated, or the newest held; frames wait for poses running late (up to 1 s: SimSource's ``known_until``)
    rather than render the arm where it was.
    """

    def __init__(
        self,
        phantom: Phantom,
        clock: Callable[[], int],
        *,
        rate_hz: float = 30.0,
        pan_deg: float = 0.0,
        tilt_deg: float = 0.0,
        camera: CameraModel | None = None,
        pixel_noise_px: float | None = None,
        geometry: ProbeGeometry = PAPER_GEOMETRY,
        errors: ProbeErrorSpec | None = DEFAULT_ERRORS,
        seed: int = 0,
        device_seed: int = 0,
        realtime: bool = False,
        tip_radius_mm: float = 2.0,
    ) -> None:
        if not (abs(pan_deg) < 90 and abs(tilt_deg) < 90):
            raise ValueError(f"SimCameraSource: pan and tilt must be within (-90, 90) deg, got {pan_deg}, {tilt_deg}")
        base = camera or CameraModel()
        if base.n_markers != geometry.n:
            raise ValueError(f"SimCameraSource: camera has {base.n_markers} markers, probe {geometry.n} indenters")
        rng = np.random.default_rng(seed)
        args = (geometry.x_mm, geometry.y_mm, geometry.k_n_per_mm, base.px_per_mm)
        self.build = (ProbeBuild.ideal(*args, stroke_mm=geometry.stroke_mm) if errors is None else
                      ProbeBuild.draw(*args, errors, np.random.default_rng(device_seed), stroke_mm=geometry.stroke_mm))
        self.build = replace(self.build, tip_radius_mm=tip_radius_mm)
        jitter = phantom.noise.pixel if pixel_noise_px is None else pixel_noise_px
        self.camera = replace(base, jitter_px=float(jitter), marker_px_per_mm=self.build.px_per_mm,
                              distortion_k1=self.build.distortion_k1, focal_px=self.build.focal_px)
        self.phantom = phantom
        self.geometry = geometry
        self.pan_rad = math.radians(pan_deg)
        self.tilt_rad = math.radians(tilt_deg)
        self._xi = np.asarray(geometry.x_mm)
        self._yi = np.asarray(geometry.y_mm)
        self._gap = self._xi * math.tan(self.pan_rad) + self._yi * math.tan(self.tilt_rad)
        self.world = CameraWorld(self.build)
        self._tissue = None if phantom.is_spring_sample else tissue_force(phantom)
        self._samples: dict[tuple[float, float], SpringRods | TissueTips] = {}
        self._renderer = Renderer(self.camera, rng)
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._source = SimSource(self._render, rate_hz, clock, realtime=realtime,
                                 known_until=lambda: self._pose.latest_stamp)
        self._t0: int | None = None
        self.occluded = np.zeros(geometry.n, dtype=bool)
        self.truth: SimTruth | None = None
        """The truth behind the last frame returned by :meth:`read`."""

    def set_pose(self, stamp_ns: int, x_mm: float, y_mm: float, z_mm: float) -> None:
        """A probe pose (phantom frame, mm) at ``stamp_ns`` (ns)."""
        self._pose.add(stamp_ns, (x_mm, y_mm, z_mm))

    def _sample(self, x_mm: float, y_mm: float) -> SpringRods | TissueTips:
        """What the tips press with the probe at (x, y): rods of the sample, or the tissue (cached per 0.1 mm)."""
        key = (round(x_mm, 1), round(y_mm, 1))
        got = self._samples.get(key)
        if got is not None:
            return got
        xs, ys = self._xi + x_mm, self._yi + y_mm
        if self._tissue is None:
            k = np.asarray(self.phantom.spring_constant(xs, ys), dtype=np.float64)
            got = SpringRods(np.nan_to_num(k, nan=0.0).tolist())
        else:
            ph = self.phantom
            got = TissueTips(self._tissue, xs.tolist(), ys.tolist(), self.build.tip_radius_mm,
                             float(ph.youngs_modulus_kpa or 0.0), ph.poisson_ratio,
                             max(float(ph.thickness(x_mm, y_mm)), 1e-3))
        if len(self._samples) > 4096:
            self._samples.clear()
        self._samples[key] = got
        return got

    def displacements(self, x_mm: float, y_mm: float, z_mm: float) -> tuple[float, FloatArray, FloatArray]:
        """(advance mm past the first contact, displacement of each indenter mm, force on each tip N)."""
        surface = np.asarray(self.phantom.surface_z(self._xi + x_mm, self._yi + y_mm), dtype=np.float64)
        overlap = surface - self._gap - z_mm
        overlap = np.where(surface > 0, overlap, -np.inf)
        state = self.world.press(np.maximum(overlap, -1e3), self._sample(x_mm, y_mm))
        return float(overlap.max()), state.dx_mm, state.force_n

    def _render(self, stamp_ns: int) -> npt.NDArray[np.uint8]:
        if self._t0 is None:
            self._t0 = stamp_ns
        pose = self._pose.at(stamp_ns, max_extrapolate_ns=1 << 62)
        n = self.geometry.n
        k_t = math.nan
        if pose is None:
            advance, dx, force = -math.inf, np.zeros(n), np.zeros(n)
        else:
            advance, dx, force = self.displacements(*pose)
            if self.phantom.is_spring_sample:
                k_t = float(self.phantom.spring_constant(pose[0], pose[1]))
        image = self._renderer.render(dx, (stamp_ns - self._t0) / 1e9, self.occluded)
        self.truth = SimTruth(stamp_ns, advance, k_t, dx, force > 0, self._renderer.last_centres_px.copy(), force)
        return image

    # FrameSource
    def open(self) -> None:
        self._source.open()

    def read(self, timeout_s: float = 0.0) -> Frame | None:
        return self._source.read(timeout_s)

    def close(self) -> None:
        self._source.close()

    def info(self) -> SourceInfo:
        return self._source.info()
