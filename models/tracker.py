"""Algorithm 1 of the camera-probe paper: four green spheres -> filtered centroids -> indenter displacements.

Per frame and per marker j (paper 2, Section IV and Algorithm 1):

1. a search box: a window of ``window_half_px`` around the marker's Kalman-filtered x and its
   last measured y, clipped to the marker's region of interest (``regions[j]``, by default the
   j-th of four vertical strips of the image, the paper's RoI_j). A marker that was lost, or
   not yet found, is searched in its whole region;
2. only that box is converted: BGR -> HSV, ``cv2.inRange`` between ``hsv_lower`` and
   ``hsv_upper`` (OpenCV hue is 0..179; green is about 60) gives the colour mask;
3. the centroid from image moments, C = (M10/M00, M01/M00), of the grayscale image inside the
   mask (the paper: "central moments on the grayscale images"; ``centroid="mask"`` uses the
   binary mask instead). A marker missing from its window, or touching a window edge, is
   measured again in the whole region, so a window that lags a fast marker never clips it;
4. a marker whose mask area (pixels) is below ``min_area_px`` is lost: its filter only
   predicts and its ``valid`` flag is False. When it is found again farther than
   ``reacquire_gate_px`` from its prediction, its filter restarts at the measurement;
5. the 1-D Kalman filter on x (q = 0.09, r = 4, p0 = 6 px², ``models.kalman``);
6. pixels -> mm: d_j = direction · (x̂_j − rest_x_j) / px_per_mm, with the rest positions
   either from a stored :class:`Calibration` or measured: the mean raw centroid over the first
   ``zero_frames`` frames in which every marker is seen (``zero_frames=1`` is the paper's
   "first image I_0"; the default 30 averages the 0.3 px centroid noise down to 0.05 px, which
   would otherwise stay in every displacement as a constant offset).

Cost: four small crops per frame instead of the whole 640x480 image (bench/tracker.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

from models.kalman import KalmanParams, ScalarKalmanBank
from models.multi_indenter import PX_PER_MM

__all__ = ["Calibration", "TrackResult", "Tracker", "TrackerConfig", "annotate", "default_regions", "poly_to_mm"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
Box = tuple[int, int, int, int]


def default_regions(width: int, height: int, n: int = 4) -> tuple[Box, ...]:
    """``n`` vertical strips covering a ``width`` x ``height`` image: (x0, y0, x1, y1), ends exclusive."""
    if n < 1 or width < n or height < 1:
        raise ValueError(f"default_regions: cannot split a {width}x{height} image into {n} strips")
    edges = [round(i * width / n) for i in range(n + 1)]
    return tuple((edges[i], 0, edges[i + 1], height) for i in range(n))


def poly_to_mm(u_px: npt.ArrayLike, scale_poly: tuple[tuple[float, ...], ...]) -> FloatArray:
    """Displacements (mm) of pixel offsets u (..., n): per marker j, sum over m of c_jm u^(m+1)."""
    u = np.asarray(u_px, dtype=np.float64)
    out = np.zeros_like(u)
    for j, coeffs in enumerate(scale_poly):
        out[..., j] = sum(c * u[..., j] ** (m + 1) for m, c in enumerate(coeffs))
    return out


@dataclass(frozen=True)
class Calibration:
    """Pixel -> mm mapping of the markers' image x.

    rest_x_px: image x (px) of each marker at zero indenter displacement; px_per_mm: image
    motion per mm of indenter travel (12.7 for the paper's probe, see models.camera_render);
    direction: +1 if compressing an indenter moves its sphere to larger x, else −1;
    scale_poly: per marker, coefficients (c1, c2, ...) of d_mm = c1 u + c2 u² + ... with
    u = direction · (x − rest) in px, a measured calibration (models.camera_calibration) that
    replaces 1 / px_per_mm and absorbs each marker's own scale and the lens's distortion.
    """

    rest_x_px: tuple[float, ...]
    px_per_mm: float = PX_PER_MM
    direction: float = 1.0
    scale_poly: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rest_x_px", tuple(float(v) for v in self.rest_x_px))
        if self.scale_poly is not None:
            poly = tuple(tuple(float(c) for c in p) for p in self.scale_poly)
            if len(poly) != len(self.rest_x_px) or not all(p and all(math.isfinite(c) for c in p) for p in poly):
                raise ValueError(f"Calibration.scale_poly: expected one list of finite coefficients per marker "
                                 f"({len(self.rest_x_px)}), got {self.scale_poly}")
            object.__setattr__(self, "scale_poly", poly)
        if not self.rest_x_px or not all(math.isfinite(v) for v in self.rest_x_px):
            raise ValueError(f"Calibration.rest_x_px: expected finite pixel positions, got {self.rest_x_px}")
        if not (self.px_per_mm > 0 and math.isfinite(self.px_per_mm)):
            raise ValueError(f"Calibration.px_per_mm: expected a finite number > 0, got {self.px_per_mm}")
        if self.direction not in (1.0, -1.0):
            raise ValueError(f"Calibration.direction: expected +1 or -1, got {self.direction}")

    def to_mm(self, x_px: npt.ArrayLike) -> FloatArray:
        """Indenter displacements (mm) for marker image x positions (px), shape (n,)."""
        x = np.asarray(x_px, dtype=np.float64)
        u = self.direction * (x - np.asarray(self.rest_x_px))
        if self.scale_poly is None:
            out: FloatArray = u / self.px_per_mm
            return out
        return poly_to_mm(u, self.scale_poly)

    def to_dict(self) -> dict[str, Any]:
        """Plain types, for a YAML/JSON calibration file."""
        out: dict[str, Any] = {"rest_x_px": list(self.rest_x_px), "px_per_mm": self.px_per_mm,
                               "direction": self.direction}
        if self.scale_poly is not None:
            out["scale_poly"] = [list(p) for p in self.scale_poly]
        return out

    @classmethod
    def from_dict(cls, doc: Any, source: str = "<dict>") -> Calibration:
        """Inverse of :meth:`to_dict`; errors name ``source`` and the key."""
        if not isinstance(doc, dict) or "rest_x_px" not in doc:
            raise ValueError(f"{source}: expected a mapping with rest_x_px (and px_per_mm, direction)")
        unknown = set(doc) - {"rest_x_px", "px_per_mm", "direction", "scale_poly"}
        if unknown:
            raise ValueError(f"{source}: unknown calibration keys {sorted(unknown)}")
        try:
            poly = doc.get("scale_poly")
            return cls(tuple(doc["rest_x_px"]), float(doc.get("px_per_mm", PX_PER_MM)),
                       float(doc.get("direction", 1.0)), None if poly is None else tuple(tuple(p) for p in poly))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from None


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker settings; the defaults match the paper's probe and ``models.camera_render.CameraModel``.

    - hsv_lower, hsv_upper: inclusive HSV range of the marker colour (H 0..179, S and V 0..255).
    - regions: one (x0, y0, x1, y1) search region per marker (px, ends exclusive), in indenter
      order; None: four vertical strips of the first frame.
    - window_half_px: half width and half height (px) of the tracking window.
    - min_area_px: a mask smaller than this (px) means the marker is lost.
    - centroid: ``"gray"`` (grayscale-weighted moments inside the mask, the paper) or ``"mask"``.
    - kalman: q, r, p0 in px² (the paper's 0.09, 4, 6).
    - px_per_mm, direction: used with measured rest positions (a stored calibration has its own).
    - zero_frames: frames averaged for the zero reference (1 = the paper's first image).
    - reacquire_gate_px: a re-found marker this far from its prediction restarts its filter.
    - scale_poly: a measured per-marker pixel -> mm polynomial (see :class:`Calibration`) used
      with measured rest positions instead of ``px_per_mm``.
    """

    hsv_lower: tuple[int, int, int] = (40, 100, 50)
    hsv_upper: tuple[int, int, int] = (85, 255, 255)
    regions: tuple[Box, ...] | None = None
    window_half_px: tuple[int, int] = (24, 18)
    min_area_px: float = 40.0
    centroid: Literal["gray", "mask"] = "gray"
    kalman: KalmanParams = field(default_factory=KalmanParams)
    px_per_mm: float = PX_PER_MM
    direction: float = 1.0
    zero_frames: int = 30
    reacquire_gate_px: float = 8.0
    scale_poly: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        for name in ("hsv_lower", "hsv_upper"):
            v = tuple(int(c) for c in getattr(self, name))
            if len(v) != 3 or not (0 <= v[0] <= 179 and 0 <= v[1] <= 255 and 0 <= v[2] <= 255):
                raise ValueError(f"TrackerConfig.{name}: expected (H 0..179, S 0..255, V 0..255), got {v}")
            object.__setattr__(self, name, v)
        if any(lo > hi for lo, hi in zip(self.hsv_lower, self.hsv_upper, strict=True)):
            raise ValueError(f"TrackerConfig: hsv_lower {self.hsv_lower} exceeds hsv_upper {self.hsv_upper}")
        if self.regions is not None:
            regions = tuple(tuple(int(c) for c in r) for r in self.regions)
            if not regions or any(len(r) != 4 or r[0] < 0 or r[1] < 0 or r[2] <= r[0] or r[3] <= r[1]
                                  for r in regions):
                raise ValueError(f"TrackerConfig.regions: expected (x0, y0, x1, y1) boxes with x1 > x0 >= 0 and "
                                 f"y1 > y0 >= 0, got {self.regions}")
            object.__setattr__(self, "regions", regions)
        w = tuple(int(v) for v in self.window_half_px)
        if len(w) != 2 or min(w) < 2:
            raise ValueError(f"TrackerConfig.window_half_px: expected (half width, half height) >= 2 px, got {w}")
        object.__setattr__(self, "window_half_px", w)
        if not self.min_area_px >= 1:
            raise ValueError(f"TrackerConfig.min_area_px: expected >= 1 px, got {self.min_area_px}")
        if self.centroid not in ("gray", "mask"):
            raise ValueError(f"TrackerConfig.centroid: expected 'gray' or 'mask', got {self.centroid!r}")
        if not (self.px_per_mm > 0 and math.isfinite(self.px_per_mm)):
            raise ValueError(f"TrackerConfig.px_per_mm: expected a finite number > 0, got {self.px_per_mm}")
        if self.direction not in (1.0, -1.0):
            raise ValueError(f"TrackerConfig.direction: expected +1 or -1, got {self.direction}")
        if self.zero_frames < 1:
            raise ValueError(f"TrackerConfig.zero_frames: expected >= 1, got {self.zero_frames}")
        if not self.reacquire_gate_px > 0:
            raise ValueError(f"TrackerConfig.reacquire_gate_px: expected > 0 px, got {self.reacquire_gate_px}")


class TrackResult(NamedTuple):
    """One frame's output (arrays have one entry per marker, in indenter order).

    centroids_px: raw measured (x, y) centroids (px), NaN for a lost marker, shape (n, 2);
    filtered_x_px: Kalman-filtered x (px; the prediction for a lost marker);
    displacement_mm: indenter displacements (mm) from the filtered x, NaN until zeroed;
    valid: marker found in this frame; m00: its colour-mask area (px, 0 when lost);
    zeroed: the zero reference exists (stored calibration, or enough frames averaged).
    """

    centroids_px: FloatArray
    filtered_x_px: FloatArray
    displacement_mm: FloatArray
    valid: BoolArray
    m00: FloatArray
    zeroed: bool


class Tracker:
    """Stateful per-frame tracker: ``Tracker(config).process(frame_bgr) -> TrackResult``.

    ``calibration`` (optional) is a stored zero reference; without one the tracker measures it
    (see the module docstring). Frames must all have the same size (BGR uint8).
    """

    def __init__(self, config: TrackerConfig | None = None, calibration: Calibration | None = None) -> None:
        self.config = config or TrackerConfig()
        self._regions: tuple[Box, ...] | None = self.config.regions
        self._fixed_cal = calibration
        self._lo = np.array(self.config.hsv_lower, dtype=np.uint8)
        self._hi = np.array(self.config.hsv_upper, dtype=np.uint8)
        self._gray = self.config.centroid == "gray"
        self._shape: tuple[int, ...] | None = None
        self.n = len(self._regions) if self._regions is not None else 0
        self.calibration: Calibration | None = calibration
        """The zero reference in use: the stored one, or the measured one once ``zero_frames`` are averaged."""
        self.frames = 0
        self.windows: list[Box] = []
        """The box each marker was last searched in (for debug overlays)."""
        self._zero_count = 0
        if self._regions is not None:
            self._init_state(len(self._regions))
        if calibration is not None and self._regions is not None and len(calibration.rest_x_px) != self.n:
            raise ValueError(f"Tracker: calibration has {len(calibration.rest_x_px)} markers, regions {self.n}")

    def _init_state(self, n: int) -> None:
        self.n = n
        self.kalman = ScalarKalmanBank(n, self.config.kalman)
        self._tracking = np.zeros(n, dtype=bool)
        self._y = [0.0] * n
        self._zero_sum = np.zeros(n)
        self._zero_count = 0
        self.calibration = self._fixed_cal
        self.frames = 0
        self.windows = [(0, 0, 0, 0)] * n

    def reset(self, keep_calibration: bool = False) -> None:
        """Forget every track (and the measured zero reference unless ``keep_calibration``)."""
        if self._regions is None:
            return
        cal = self.calibration
        self._init_state(self.n)
        if keep_calibration:
            self.calibration = cal

    @property
    def zero_progress(self) -> int:
        """Frames averaged so far for the measured zero reference."""
        return self._zero_count

    @property
    def last_y_px(self) -> tuple[float, ...]:
        """Each marker's last measured image y (px); 0 before it was first seen, empty before the first frame."""
        return tuple(self._y) if self.n else ()

    @property
    def regions(self) -> tuple[Box, ...] | None:
        """The per-marker search regions (None until the first frame when not configured)."""
        return self._regions

    def process(self, frame: npt.NDArray[np.uint8]) -> TrackResult:
        """Track one BGR uint8 frame (height, width, 3); see the module docstring for the steps."""
        if self._shape is None:
            if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
                raise ValueError(f"Tracker: expected a BGR uint8 image (h, w, 3), got {frame.dtype} {frame.shape}")
            h, w = frame.shape[:2]
            if self._regions is None:
                n = len(self._fixed_cal.rest_x_px) if self._fixed_cal is not None else 4
                self._regions = default_regions(w, h, n)
                self._init_state(n)
            bad = [r for r in self._regions if r[2] > w or r[3] > h]
            if bad:
                raise ValueError(f"Tracker: regions {bad} extend beyond the {w}x{h} frame")
            if self._fixed_cal is not None and len(self._fixed_cal.rest_x_px) != self.n:
                raise ValueError(f"Tracker: calibration has {len(self._fixed_cal.rest_x_px)} markers, "
                                 f"regions {self.n}")
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"Tracker: frame shape {frame.shape} differs from the first frame's {self._shape}")
        regions = self._regions
        if regions is None:  # unreachable: set from the first frame above
            raise RuntimeError("Tracker: no regions")
        n = self.n
        half_w, half_h = self.config.window_half_px
        min_area = self.config.min_area_px
        # Python scalars in the per-marker loop: numpy scalar access costs more than the arithmetic.
        xs = self.kalman.x.tolist()
        ys = self._y
        tracking = self._tracking.tolist()
        cx, cy, area = [math.nan] * n, [math.nan] * n, [0.0] * n
        for j in range(n):
            region = regions[j]
            box = region
            if tracking[j]:
                xc, yc = round(xs[j]), round(ys[j])
                win = (max(region[0], xc - half_w), max(region[1], yc - half_h),
                       min(region[2], xc + half_w + 1), min(region[3], yc + half_h + 1))
                if win[0] < win[2] and win[1] < win[3]:
                    box = win
            m = self._measure(frame, box)
            if box is not region and (m is None or _touches_edge(m, box, region)):
                # gone from the window, or cut by its edge: look in the whole region this same frame
                box = region
                m = self._measure(frame, box)
            self.windows[j] = box
            if m is not None and m[2] >= min_area:
                cx[j], cy[j], area[j] = m
                ys[j] = m[1]
        z = np.array(cx)
        valid = np.array(area) >= min_area
        self._filter(z, valid)
        self._tracking = valid
        self.frames += 1
        if self.calibration is None and valid.all():
            self._zero_sum += z
            self._zero_count += 1
            if self._zero_count >= self.config.zero_frames:
                self.calibration = Calibration(tuple((self._zero_sum / self._zero_count).tolist()),
                                               self.config.px_per_mm, self.config.direction, self.config.scale_poly)
        filtered = self.kalman.x.copy()
        filtered[~self.kalman.initialized] = np.nan
        cal = self.calibration
        disp = cal.to_mm(filtered) if cal is not None else np.full(n, np.nan)
        return TrackResult(np.array((cx, cy)).T, filtered, disp, valid, np.array(area), cal is not None)

    def _filter(self, z: FloatArray, valid: BoolArray) -> None:
        """Kalman step; a marker found again far from its prediction restarts at the measurement."""
        k = self.kalman
        k.predict()
        jump = valid & ~self._tracking & k.initialized
        if jump.any():
            jump &= np.abs(np.where(jump, z, k.x) - k.x) > self.config.reacquire_gate_px
            if jump.any():
                k.reset(np.where(jump, z, 0.0), jump)
        k.update(z, valid & ~jump)

    def _measure(self, frame: npt.NDArray[np.uint8], box: Box) -> tuple[float, float, float] | None:
        """(x, y, mask area) of the marker in ``box`` (frame px), or None when too little colour."""
        x0, y0, x1, y1 = box
        crop = frame[y0:y1, x0:x1]
        mask = cv2.inRange(cv2.cvtColor(crop, cv2.COLOR_BGR2HSV), self._lo, self._hi)
        area = cv2.countNonZero(mask)
        if area < self.config.min_area_px:
            return None
        if self._gray:
            mo = cv2.moments(cv2.bitwise_and(cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY), mask))
        else:
            mo = cv2.moments(mask, True)
        m00 = mo["m00"]
        if m00 <= 0:
            return None
        return x0 + mo["m10"] / m00, y0 + mo["m01"] / m00, float(area)


def _touches_edge(m: tuple[float, float, float], box: Box, region: Box) -> bool:
    """Whether a blob (centroid, area) may be cut by a side of ``box`` that is not a side of ``region``."""
    x, y, area = m
    r = math.sqrt(area / math.pi) + 2.0  # the disc the mask covers, plus blur and anti-aliasing
    return ((box[0] > region[0] and x - r < box[0]) or (box[2] < region[2] and x + r > box[2] - 1)
            or (box[1] > region[1] and y - r < box[1]) or (box[3] < region[3] and y + r > box[3] - 1))


def annotate(frame: npt.NDArray[np.uint8], result: TrackResult, windows: list[Box]) -> npt.NDArray[np.uint8]:
    """A copy of ``frame`` with each search window (green: found, red: lost) and filtered position drawn."""
    out = frame.copy()
    for j, (x0, y0, x1, y1) in enumerate(windows):
        colour = (0, 255, 0) if result.valid[j] else (0, 0, 255)
        cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), colour, 1)
        x = result.filtered_x_px[j]
        if math.isfinite(x):
            yc = (y0 + y1) // 2 if not math.isfinite(result.centroids_px[j, 1]) else int(result.centroids_px[j, 1])
            cv2.drawMarker(out, (int(round(x)), yc), (255, 255, 255), cv2.MARKER_CROSS, 9, 1)
    return out
