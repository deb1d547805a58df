"""Simulated probe camera: frames of the four spheres rendered from the robot pose and the phantom.

The probe's reference point (the pose on ``robot/pose``) is the tip of the central, hard indenter at rest; the
probe axis is the phantom's −z (the probe presses down). Under it the sample's surface is a plane through
``phantom.surface_z(x, y)`` inclined by ``pan`` (slope along the probe's x) and ``tilt`` (along y), the angles of
models.multi_indenter (a positive angle: the surface recedes from the probe towards +x / +y). Pressing the probe
``depth = surface_z − z`` past the surface at its centre advances it ``depth − min_i gap_i`` past its first
contact (gap_i = x_i tan pan + y_i tan tilt for indenter tip i); ``multi_indenter.forward`` then gives each
indenter's displacement against the local stiffness K_t = ``phantom.spring_constant(x, y)`` (uniform under the
probe, as eq. 5 assumes; on tissue taken at the depth the centre indenter pushes the surface to, so a buried
inclusion shows more the deeper the press), and ``models.camera_render`` draws the frame.

Implements :class:`nodes.drivers.camera.FrameSource`; the node feeds it poses from the bus.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from models.camera_render import CameraModel, Renderer
from models.multi_indenter import PAPER_GEOMETRY, ProbeGeometry, forward
from models.phantom import Phantom
from models.timeseries import StampedBuffer
from nodes.drivers.camera import Frame, SimSource, SourceInfo

__all__ = ["SimCameraSource", "SimTruth"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SimTruth:
    """What the last rendered frame shows: the truth a tracker and an estimator are judged against.

    stamp_ns; advance_mm past first contact (<= 0: not touching); k_t_n_per_mm (NaN off the sample);
    displacement_mm of each indenter; contact flags; centres_px drawn (jitter included).
    """

    stamp_ns: int
    advance_mm: float
    k_t_n_per_mm: float
    displacement_mm: FloatArray
    contact: npt.NDArray[np.bool_]
    centres_px: FloatArray


class SimCameraSource:
    """A :class:`~nodes.drivers.camera.FrameSource` rendering the probe camera at ``rate_hz`` of ``clock``.

    ``pan_deg``/``tilt_deg``: the sample surface's inclination relative to the probe (degrees, < 90);
    ``camera``: the image model (its ``jitter_px`` is replaced by ``pixel_noise_px`` when given, else by the
    phantom's ``noise.pixel``). ``occluded`` (settable, bool per marker) hides spheres, for lost-marker tests.
    Before any pose arrives the probe is taken to be off the sample (spheres at rest); afterwards the pose at
    each frame's stamp is interpolated, or the newest held.
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
        seed: int = 0,
        realtime: bool = False,
    ) -> None:
        if not (abs(pan_deg) < 90 and abs(tilt_deg) < 90):
            raise ValueError(f"SimCameraSource: pan and tilt must be within (-90, 90) deg, got {pan_deg}, {tilt_deg}")
        base = camera or CameraModel()
        jitter = phantom.noise.pixel if pixel_noise_px is None else pixel_noise_px
        self.camera = replace(base, jitter_px=float(jitter))
        if self.camera.n_markers != geometry.n:
            raise ValueError(f"SimCameraSource: camera has {self.camera.n_markers} markers, probe {geometry.n} indenters")
        self.phantom = phantom
        self.geometry = geometry
        self.pan_rad = math.radians(pan_deg)
        self.tilt_rad = math.radians(tilt_deg)
        gaps = [x * math.tan(self.pan_rad) + y * math.tan(self.tilt_rad)
                for x, y in zip(geometry.x_mm, geometry.y_mm, strict=True)]
        self._min_gap = min(gaps)
        self._renderer = Renderer(self.camera, np.random.default_rng(seed))
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._source = SimSource(self._render, rate_hz, clock, realtime=realtime)
        self._t0: int | None = None
        self.occluded = np.zeros(geometry.n, dtype=bool)
        self.truth: SimTruth | None = None
        """The truth behind the last frame returned by :meth:`read`."""

    def set_pose(self, stamp_ns: int, x_mm: float, y_mm: float, z_mm: float) -> None:
        """A probe pose (phantom frame, mm) at ``stamp_ns`` (ns)."""
        self._pose.add(stamp_ns, (x_mm, y_mm, z_mm))

    def displacements(self, x_mm: float, y_mm: float, z_mm: float) -> tuple[float, float, FloatArray, npt.NDArray[np.bool_]]:
        """(advance mm, K_t N/mm, displacement of each indenter mm, contact) for the probe at (x, y, z)."""
        surface = float(self.phantom.surface_z(x_mm, y_mm))
        advance = surface - z_mm - self._min_gap
        k_t = float(self.phantom.spring_constant(x_mm, y_mm))
        if not self.phantom.is_spring_sample and math.isfinite(k_t) and k_t > 0 and advance > 0:
            # tissue: the deeper the centre (hard) indenter pushes the surface, the deeper the material it feels
            # (a buried inclusion shows more); its tissue displacement is advance * K_h / (K_h + K_t)
            k_h = max(self.geometry.k_n_per_mm)
            k_t = float(self.phantom.spring_constant(x_mm, y_mm, depth_mm=advance * k_h / (k_h + k_t)))
        if not (math.isfinite(k_t) and k_t > 0 and math.isfinite(advance)):
            return advance, k_t, np.zeros(self.geometry.n), np.zeros(self.geometry.n, dtype=bool)
        c = forward(self.geometry, k_t, advance, self.pan_rad, self.tilt_rad)
        return advance, k_t, np.asarray(c.dx_mm, dtype=np.float64), np.asarray(c.contact)

    def _render(self, stamp_ns: int) -> npt.NDArray[np.uint8]:
        if self._t0 is None:
            self._t0 = stamp_ns
        pose = self._pose.at(stamp_ns, max_extrapolate_ns=1 << 62)
        if pose is None:
            advance, k_t = -math.inf, math.nan
            dx, contact = np.zeros(self.geometry.n), np.zeros(self.geometry.n, dtype=bool)
        else:
            advance, k_t, dx, contact = self.displacements(*pose)
        image = self._renderer.render(dx, (stamp_ns - self._t0) / 1e9, self.occluded)
        self.truth = SimTruth(stamp_ns, advance, k_t, dx, contact, self._renderer.last_centres_px.copy())
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
