"""Synthetic camera frames of the multi-indenter probe (paper 2, Sections III-IV).

The probe's camera looks at four green spheres, one per indenter; an indenter displacement
Δz moves its sphere along the image x axis (Fig. 3(b)). We render BGR uint8 frames (640x480
by default, the paper's USB camera) of that view with sub-pixel accurate sphere positions,
for the sim camera driver and for testing the tracker against known ground truth.

Scale. The paper states the resolution as "12.7 mm per pixel, i.e. when ... the indenter
[moves] 12.7 mm, the centroid changes by one pixel". For indenter travel of a few mm that
would be far below one pixel of motion, which contradicts a working tracker; we read it as
12.7 px per mm (≈ 79 µm per px, ``models.multi_indenter.PX_PER_MM``) and make it a parameter,
``CameraModel.px_per_mm``.

Image formation (pixel units; pixel (row i, column j) is centred on (x, y) = (j, i), the
convention of cv2.moments, so a measured centroid compares directly with the truth here):
- background: a flat dark grey;
- sphere j: a disc of ``sphere_radius_px`` centred on (x_j, y_j) with
  x_j = rest_x_px[j] + direction · px_per_mm · d_j, y_j = y_px[j]; the coverage of a pixel is
  the linear ramp clip(r + 0.5 − ρ, 0, 1) of the distance ρ from the pixel centre
  (anti-aliased and symmetric, so intensity centroids are unbiased to well under 0.05 px);
  shading is Lambertian for a light on the optical axis, ambient + (1 − ambient)·cos;
- per-frame position jitter (σ ``jitter_px`` in x and y, independent per sphere): the raw
  centroid noise of the real probe (vibration, rolling shutter, compression), 0.3 px by
  default, the paper-level figure the estimator's accuracy is judged with;
- Gaussian blur (σ px), a slow global lighting gain 1 + a·sin(2πt/T), additive sensor noise
  (σ in 8-bit DN), and occluded spheres that are not drawn at all.

Speed. The background is flat, so blur is applied to each sphere's patch only (with a margin
of 4σ, where the patch border is plain background, this equals blurring the whole frame), and
sensor noise comes from a bank of pre-drawn noise read at a random offset each frame (two
saturating uint8 adds). A 640x480 frame costs well under a millisecond, so the sim camera
can run at 30 fps beside the rest of the graph. Noise of consecutive frames is therefore not
independent draws but shifted windows of one bank (``noise_bank_frames`` frames long); for
the tracker it is indistinguishable from fresh noise.

Pure: no I/O; randomness only from the ``numpy.random.Generator`` given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from models.multi_indenter import CENTROID_NOISE_PX, PX_PER_MM

__all__ = ["CameraModel", "Renderer", "marker_x_px", "render", "true_centroids_px"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
U8Image = npt.NDArray[np.uint8]


def _floats(values: tuple[float, ...] | list[float], name: str, n: int) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if len(out) != n:
        raise ValueError(f"CameraModel.{name}: expected {n} values (one per marker), got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"CameraModel.{name}: values must be finite, got {out}")
    return out


def _bgr(values: tuple[float, ...] | list[float], name: str) -> tuple[float, float, float]:
    out = _floats(values, name, 3)
    if not all(0.0 <= v <= 255.0 for v in out):
        raise ValueError(f"CameraModel.{name}: expected 3 values in 0..255 (B, G, R), got {out}")
    return out[0], out[1], out[2]


@dataclass(frozen=True)
class CameraModel:
    """Geometry, appearance and noise of the rendered probe camera.

    Units: pixels (px) for positions and sizes, px/mm for the scale, 8-bit digital numbers
    (DN, 0..255) for colours and sensor noise, seconds for times.

    - width, height: image size (px); the probe's USB camera is 640x480.
    - px_per_mm: image x motion per mm of indenter displacement (see the module docstring).
    - direction: +1 if a positive (compressing) displacement moves the sphere to larger x, else −1.
    - rest_x_px, y_px: sphere centres (px) at zero displacement, one per marker. The defaults
      put marker j 18 px from the left edge of the j-th 160 px vertical strip, so the whole
      10 mm stroke (127 px) plus the sphere stays inside the strip; rows alternate so that
      neighbouring spheres never share a tracking window.
    - sphere_radius_px: sphere radius in the image (px).
    - sphere_bgr, background_bgr: colours (DN); ambient: shading at the sphere's limb (0..1).
    - jitter_px: Gaussian jitter σ (px) of each sphere's x and y, drawn every frame.
    - blur_sigma_px: Gaussian blur σ (px), 0 = none.
    - noise_dn: additive Gaussian sensor noise σ (DN), 0 = none.
    - drift_amplitude, drift_period_s: lighting gain 1 + a·sin(2π t / T).
    - marker_px_per_mm: the scale of each marker (px/mm) when they differ (a probe as built);
      None: ``px_per_mm`` for all.
    - distortion_k1, focal_px: radial lens distortion about the image centre applied to the
      sphere centres, x_d = c + (x − c)(1 + k1 r²) with r = |x − c| / focal_px (barrel: k1 < 0).
    """

    width: int = 640
    height: int = 480
    px_per_mm: float = PX_PER_MM
    direction: float = 1.0
    rest_x_px: tuple[float, ...] = (18.0, 178.0, 338.0, 498.0)
    y_px: tuple[float, ...] = (200.0, 280.0, 200.0, 280.0)
    sphere_radius_px: float = 12.0
    sphere_bgr: tuple[float, float, float] = (40.0, 200.0, 50.0)
    background_bgr: tuple[float, float, float] = (48.0, 44.0, 40.0)
    ambient: float = 0.45
    jitter_px: float = CENTROID_NOISE_PX
    blur_sigma_px: float = 0.7
    noise_dn: float = 2.0
    drift_amplitude: float = 0.08
    drift_period_s: float = 20.0
    marker_px_per_mm: tuple[float, ...] | None = None
    distortion_k1: float = 0.0
    focal_px: float = 600.0

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int) and isinstance(self.height, int)) or min(self.width, self.height) < 16:
            raise ValueError(f"CameraModel: width and height must be integers >= 16 px, got {self.width}x{self.height}")
        n = len(self.rest_x_px)
        if n < 1:
            raise ValueError("CameraModel.rest_x_px: need at least one marker")
        object.__setattr__(self, "rest_x_px", _floats(self.rest_x_px, "rest_x_px", n))
        object.__setattr__(self, "y_px", _floats(self.y_px, "y_px", n))
        object.__setattr__(self, "sphere_bgr", _bgr(self.sphere_bgr, "sphere_bgr"))
        object.__setattr__(self, "background_bgr", _bgr(self.background_bgr, "background_bgr"))
        if not (self.px_per_mm > 0 and math.isfinite(self.px_per_mm)):
            raise ValueError(f"CameraModel.px_per_mm: expected a finite number > 0, got {self.px_per_mm}")
        if self.direction not in (1.0, -1.0):
            raise ValueError(f"CameraModel.direction: expected +1 or -1, got {self.direction}")
        if not (self.sphere_radius_px > 1.0 and math.isfinite(self.sphere_radius_px)):
            raise ValueError(f"CameraModel.sphere_radius_px: expected > 1 px, got {self.sphere_radius_px}")
        for name in ("jitter_px", "blur_sigma_px", "noise_dn", "drift_amplitude"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"CameraModel.{name}: expected a finite number >= 0, got {value}")
        if not 0.0 <= self.ambient <= 1.0:
            raise ValueError(f"CameraModel.ambient: expected 0..1, got {self.ambient}")
        if not self.drift_amplitude < 1.0:
            raise ValueError(f"CameraModel.drift_amplitude: expected < 1, got {self.drift_amplitude}")
        if self.marker_px_per_mm is not None:
            scales = _floats(self.marker_px_per_mm, "marker_px_per_mm", n)
            if not all(v > 0 for v in scales):
                raise ValueError(f"CameraModel.marker_px_per_mm: expected values > 0, got {scales}")
            object.__setattr__(self, "marker_px_per_mm", scales)
        if not (math.isfinite(self.distortion_k1) and abs(self.distortion_k1) < 1.0 and self.focal_px > 0):
            raise ValueError(f"CameraModel: distortion_k1 must be in (-1, 1) and focal_px > 0, got "
                             f"{self.distortion_k1}, {self.focal_px}")
        if not self.drift_period_s > 0:
            raise ValueError(f"CameraModel.drift_period_s: expected > 0 s, got {self.drift_period_s}")

    @property
    def n_markers(self) -> int:
        """Number of spheres (4 for the paper's probe)."""
        return len(self.rest_x_px)

    def gain(self, t_s: float) -> float:
        """Lighting gain (dimensionless) at time ``t_s`` (s)."""
        if self.drift_amplitude == 0:
            return 1.0
        return 1.0 + self.drift_amplitude * math.sin(2.0 * math.pi * t_s / self.drift_period_s)


def marker_x_px(model: CameraModel, displacements_mm: npt.ArrayLike) -> FloatArray:
    """Image x (px) of each sphere centre for indenter displacements (mm), shape (n,), no jitter."""
    d = np.asarray(displacements_mm, dtype=np.float64)
    if d.shape != (model.n_markers,):
        raise ValueError(f"displacements_mm: expected shape ({model.n_markers},), got {d.shape}")
    scale = model.px_per_mm if model.marker_px_per_mm is None else np.asarray(model.marker_px_per_mm)
    return np.asarray(model.rest_x_px) + model.direction * scale * d


def true_centroids_px(model: CameraModel, displacements_mm: npt.ArrayLike) -> FloatArray:
    """Nominal sphere centres (x, y) in px, shape (n, 2), without jitter, lens distortion applied.

    Pixel (row i, column j) is centred on (x, y) = (j, i), as in cv2.moments, so these
    compare directly with centroids measured from image moments.
    """
    xy = np.empty((model.n_markers, 2))
    xy[:, 0] = marker_x_px(model, displacements_mm)
    xy[:, 1] = model.y_px
    if model.distortion_k1:
        c = np.array([(model.width - 1) / 2.0, (model.height - 1) / 2.0])
        r2 = np.sum((xy - c) ** 2, axis=1, keepdims=True) / model.focal_px**2
        xy = c + (xy - c) * (1.0 + model.distortion_k1 * r2)
    return xy


class Renderer:
    """Renders a stream of frames of one :class:`CameraModel` (fast; see the module docstring).

    ``last_centres_px`` holds the centres (x, y) actually drawn in the last frame, jitter
    included, shape (n, 2): the ground truth a tracker's raw centroids are compared with.
    """

    def __init__(self, model: CameraModel, rng: np.random.Generator, *, noise_bank_frames: float = 3.0) -> None:
        if not noise_bank_frames >= 1.0:
            raise ValueError(f"Renderer: noise_bank_frames must be >= 1, got {noise_bank_frames}")
        self.model = model
        self.rng = rng
        self.last_centres_px = true_centroids_px(model, np.zeros(model.n_markers))
        self._frame_len = model.height * model.width * 3
        self._noise_pos: U8Image | None = None
        self._noise_neg: U8Image | None = None
        if model.noise_dn > 0:
            # Integer noise split into its positive and negative parts: two saturating uint8
            # adds (cv2.add / cv2.subtract) apply it without a wider intermediate image.
            bank = np.rint(rng.standard_normal(int(self._frame_len * noise_bank_frames), dtype=np.float32)
                           * np.float32(model.noise_dn))
            self._noise_pos = np.clip(bank, 0, 255).astype(np.uint8)
            self._noise_neg = np.clip(-bank, 0, 255).astype(np.uint8)
        r = model.sphere_radius_px
        self._margin = int(math.ceil(r + 1.5 + 4.0 * model.blur_sigma_px)) + 1
        self._colour = np.asarray(model.sphere_bgr, dtype=np.float32)
        self._row = np.empty((model.width, 3), dtype=np.uint8)

    def render(
        self, displacements_mm: npt.ArrayLike, t_s: float = 0.0, occluded: npt.ArrayLike | None = None
    ) -> U8Image:
        """One BGR uint8 frame (height, width, 3) for indenter displacements (mm), shape (n,).

        ``t_s`` (s) drives the lighting drift; ``occluded`` is an optional boolean mask (n,) of
        spheres not to draw (lost markers). Spheres are drawn where their centre puts them,
        clipped at the image border.
        """
        m = self.model
        centres = true_centroids_px(m, displacements_mm)
        hidden = np.zeros(m.n_markers, dtype=bool) if occluded is None else np.asarray(occluded, dtype=bool)
        if hidden.shape != (m.n_markers,):
            raise ValueError(f"occluded: expected a boolean mask of shape ({m.n_markers},), got {hidden.shape}")
        if m.jitter_px > 0:
            centres += self.rng.normal(0.0, m.jitter_px, size=centres.shape)
        self.last_centres_px = centres
        g = m.gain(t_s)
        frame = np.empty((m.height, m.width, 3), dtype=np.uint8)
        # Broadcasting whole rows: a (3,) colour broadcast over the frame is ~50x slower.
        self._row[:] = np.rint(np.asarray(m.background_bgr) * g).clip(0, 255).astype(np.uint8)
        frame[:] = self._row
        colour = self._colour * np.float32(g)
        for j in range(m.n_markers):
            if not hidden[j]:
                self._draw_sphere(frame, float(centres[j, 0]), float(centres[j, 1]), colour)
        if self._noise_pos is not None and self._noise_neg is not None:
            start = int(self.rng.integers(0, self._noise_pos.size - self._frame_len + 1))
            shape = frame.shape
            cv2.add(frame, self._noise_pos[start:start + self._frame_len].reshape(shape), dst=frame)
            cv2.subtract(frame, self._noise_neg[start:start + self._frame_len].reshape(shape), dst=frame)
        return frame

    def _draw_sphere(self, frame: U8Image, cx: float, cy: float, colour: npt.NDArray[np.float32]) -> None:
        """Composite one anti-aliased, Lambert-shaded, blurred sphere into ``frame`` in place."""
        m = self.model
        h, w = frame.shape[:2]
        r, k = m.sphere_radius_px, self._margin
        x0, x1 = max(int(math.floor(cx)) - k, 0), min(int(math.floor(cx)) + k + 2, w)
        y0, y1 = max(int(math.floor(cy)) - k, 0), min(int(math.floor(cy)) + k + 2, h)
        if x0 >= x1 or y0 >= y1:
            return
        # Pixel (i, j) is sampled at (j, i): the grid cv2.moments integrates over.
        dx = np.arange(x0, x1, dtype=np.float32) - np.float32(cx)
        dy = np.arange(y0, y1, dtype=np.float32) - np.float32(cy)
        rho2 = dy[:, None] ** 2 + dx[None, :] ** 2
        alpha = np.clip(np.float32(r + 0.5) - np.sqrt(rho2), 0.0, 1.0)
        cos_n = np.sqrt(np.clip(1.0 - rho2 * np.float32(1.0 / (r * r)), 0.0, 1.0))
        fill = alpha * (np.float32(m.ambient) + np.float32(1.0 - m.ambient) * cos_n)
        view = frame[y0:y1, x0:x1]
        patch = view.astype(np.float32)
        patch *= (1.0 - alpha)[:, :, None]
        patch += fill[:, :, None] * colour
        if m.blur_sigma_px > 0:
            # The patch border is background (margin >= 4 sigma), so replicating it is exact.
            patch = np.asarray(cv2.GaussianBlur(patch, (0, 0), m.blur_sigma_px, borderType=cv2.BORDER_REPLICATE),
                               dtype=np.float32)
        np.clip(patch, 0.0, 255.0, out=patch)
        np.rint(patch, out=patch)
        view[...] = patch.astype(np.uint8)


def render(
    model: CameraModel,
    displacements_mm: npt.ArrayLike,
    rng: np.random.Generator,
    t_s: float = 0.0,
    occluded: npt.ArrayLike | None = None,
) -> U8Image:
    """Render one frame with freshly drawn noise (one-shot; use :class:`Renderer` for streams).

    Same image model as :meth:`Renderer.render`; about 20 ms because a frame's worth of
    sensor noise is drawn each call.
    """
    return Renderer(model, rng, noise_bank_frames=1.0).render(displacements_mm, t_s, occluded)
