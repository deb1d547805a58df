"""Multi-indenter camera probe: forward model and inverse of eq. 5 (Faragasso et al., paper 2).

Geometry and sign conventions (probe frame, mm): x, y span the plane of the indenter tips at
rest, z points along the probe axis into the tissue. The undeformed surface is the plane
``gap(x, y) = gap0 + x tan(pan) + y tan(tilt)`` measured along z, i.e. pan (the paper's θ) is
the surface slope along x and tilt (the paper's α) the slope along y; a positive angle means
the surface recedes from the probe towards +x (+y). With ``d_ijx = x_j - x_i`` this is exactly
the sign of eq. 5. Each indenter i (spring k_i) and the tissue under it (a local spring K_t,
like the paper's spring samples) are springs in series, so with ``overlap_i`` the probe's
advance past the undeformed surface at indenter i:

    dx_i + dt_i = overlap_i,   k_i dx_i = K_t dt_i        (eq. 5, rows 1-4 and 5-7)

The inverse (eq. 5 solved for K_t, pan and tilt) is ``models.multi_indenter_solve``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "CENTROID_NOISE_PX",
    "PAPER_GEOMETRY",
    "PX_PER_MM",
    "ProbeContact",
    "ProbeGeometry",
    "advance_range_mm",
    "forward",
    "geometry_columns",
]

#: Image scale of the tracker. The paper writes "12.7 mm per pixel ... a movement of the
#: indenter of 12.7 mm changes the centroid by one pixel", which would put the whole 640 px
#: image at 8 m; we read it as 12.7 px per mm (0.079 mm per px).
PX_PER_MM = 12.7
#: Centroid noise of the sphere tracker before its Kalman filter (px, one sigma).
CENTROID_NOISE_PX = 0.3


def geometry_columns(
    x: Sequence[float], y: Sequence[float], idx: Sequence[int]
) -> tuple[float, ...]:
    """Constant columns X, Y of the 3x3 system for indenters ``idx`` (first = reference),
    N = X x Y and the squared norms |X|^2, |Y|^2, |N|^2 (Python floats; shared by both paths)."""
    a, j, k, m = (int(i) for i in idx)
    x2, x3, x4 = x[j] - x[a], x[k] - x[a], x[m] - x[a]
    y2, y3, y4 = y[j] - y[a], y[k] - y[a], y[m] - y[a]
    n2, n3, n4 = x3 * y4 - x4 * y3, x4 * y2 - x2 * y4, x2 * y3 - x3 * y2
    xx, yy = x2 * x2 + x3 * x3 + x4 * x4, y2 * y2 + y3 * y3 + y4 * y4
    return (x2, x3, x4, y2, y3, y4, n2, n3, n4, xx, yy, n2 * n2 + n3 * n3 + n4 * n4)


@dataclass(frozen=True, slots=True)
class ProbeGeometry:
    """Indenter tip positions (mm, probe frame), spring constants (N/mm) and stroke (mm)."""

    x_mm: tuple[float, ...]
    y_mm: tuple[float, ...]
    k_n_per_mm: tuple[float, ...]
    stroke_mm: float = 10.0
    # Constant columns of the 4-contact system against indenter 1 (see geometry_columns).
    columns: tuple[float, ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        n = len(self.k_n_per_mm)
        if n < 4 or len(self.x_mm) != n or len(self.y_mm) != n:
            raise ValueError(
                f"ProbeGeometry: need >= 4 indenters with one x, y and k each, got "
                f"{len(self.x_mm)} x, {len(self.y_mm)} y, {n} k"
            )
        values = (*self.x_mm, *self.y_mm, self.stroke_mm)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"ProbeGeometry: positions and stroke must be finite, got {values}")
        if not all(math.isfinite(k) and k > 0 for k in self.k_n_per_mm):
            raise ValueError(
                f"ProbeGeometry: spring constants must be > 0 N/mm, got {self.k_n_per_mm}"
            )
        if self.stroke_mm <= 0:
            raise ValueError(f"ProbeGeometry: stroke_mm must be > 0, got {self.stroke_mm}")
        object.__setattr__(self, "columns", geometry_columns(self.x_mm, self.y_mm, (0, 1, 2, 3)))

    @property
    def n(self) -> int:
        """Number of indenters."""
        return len(self.k_n_per_mm)

    @classmethod
    def paper(
        cls,
        radius_mm: float = 8.0,
        k_soft_n_per_mm: float = 0.05,
        k_hard_n_per_mm: float = 0.25,
        interval_deg: float = 102.0,
        stroke_mm: float = 10.0,
    ) -> ProbeGeometry:
        """The paper's probe: hard spring at the centre, three soft ones on a circle.

        Numbering follows eq. 5, where only row 2 carries K_h: indenter 2 is the hard one at
        the origin; soft indenters 1, 3, 4 sit on a circle of ``radius_mm`` at 90°,
        90° - interval and 90° + interval from +x (paper: "a circle at 102° intervals";
        symmetric about the y axis). Fig. 3's exact positions are not in our copy: the 8 mm
        radius is our assumption (tilt resolution scales with it). The paper also calls the
        centre the triangle's barycentre, true only for 120°; we keep the hard one at the
        circle's centre. Stroke: a sphere moving along x inside one of four 160 px wide
        image strips at 12.7 px/mm has about 12.6 mm of travel minus its own size; 10 mm.
        """
        angles = (90.0, None, 90.0 - interval_deg, 90.0 + interval_deg)
        xs = tuple(0.0 if a is None else radius_mm * math.cos(math.radians(a)) for a in angles)
        ys = tuple(0.0 if a is None else radius_mm * math.sin(math.radians(a)) for a in angles)
        ks = (k_soft_n_per_mm, k_hard_n_per_mm, k_soft_n_per_mm, k_soft_n_per_mm)
        return cls(xs, ys, ks, stroke_mm)


PAPER_GEOMETRY = ProbeGeometry.paper()


class ProbeContact(NamedTuple):
    """Forward-model output; arrays have the broadcast input shape plus a last axis of n."""

    dx_mm: FloatArray  # indenter (sphere) displacement, mm
    dt_mm: FloatArray  # tissue displacement under each indenter, mm
    contact: BoolArray  # indenter touches the surface
    saturated: BoolArray  # indenter reached the end of its stroke (then dx = stroke)


def forward(
    geometry: ProbeGeometry,
    k_t_n_per_mm: npt.ArrayLike,
    advance_mm: npt.ArrayLike,
    pan_rad: npt.ArrayLike = 0.0,
    tilt_rad: npt.ArrayLike = 0.0,
) -> ProbeContact:
    """Indenter and tissue displacements (mm) for a probe pressed onto a tilted surface.

    ``advance_mm`` is the probe's travel along its axis past first contact (the first
    indenter to touch); indenters whose surface point is farther away than that do not
    touch (dx = dt = 0). An indenter at the end of its stroke stops (dx = stroke_mm) and the
    probe body pushes the tissue the rest of the way. Inputs broadcast (numpy rules).
    """
    k_t, adv, pan, tilt = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (k_t_n_per_mm, advance_mm, pan_rad, tilt_rad))
    )
    if not (np.all(np.isfinite(k_t)) and np.all(k_t > 0)):
        raise ValueError(f"forward: k_t_n_per_mm must be finite and > 0, got {k_t_n_per_mm!r}")
    if not (np.all(np.abs(pan) < math.pi / 2) and np.all(np.abs(tilt) < math.pi / 2)):
        raise ValueError("forward: pan_rad and tilt_rad must lie in (-pi/2, pi/2)")
    if not np.all(np.isfinite(adv)):
        raise ValueError(f"forward: advance_mm must be finite, got {advance_mm!r}")
    x = np.asarray(geometry.x_mm)
    y = np.asarray(geometry.y_mm)
    k = np.asarray(geometry.k_n_per_mm)
    gap = x * np.tan(pan)[..., None] + y * np.tan(tilt)[..., None]
    overlap = adv[..., None] - (gap - gap.min(axis=-1, keepdims=True))
    contact = overlap > 0
    kt = k_t[..., None]
    dx_free = np.where(contact, overlap * kt / (k + kt), 0.0)
    saturated = dx_free > geometry.stroke_mm
    dx = np.minimum(dx_free, geometry.stroke_mm)
    dt = np.where(contact, overlap - dx, 0.0)
    return ProbeContact(dx, dt, contact, saturated)


def advance_range_mm(
    geometry: ProbeGeometry, k_t_n_per_mm: float, pan_rad: float = 0.0, tilt_rad: float = 0.0
) -> tuple[float, float]:
    """Advances (mm past first contact) usable for a solve: above the first, every indenter
    touches; up to the second, none is at its stroke end. The first exceeds the second when
    the tilt is too steep for the stroke. Example: the paper's 18 mm press needs a stroke of
    16.7 mm on the 0.63 N/mm spring; with our 10 mm stroke the flat limit is 10.8 mm.
    """
    gap = [
        x * math.tan(pan_rad) + y * math.tan(tilt_rad)
        for x, y in zip(geometry.x_mm, geometry.y_mm, strict=True)
    ]
    offset = [g - min(gap) for g in gap]
    kt = k_t_n_per_mm
    top = min(
        geometry.stroke_mm * (k + kt) / kt + o
        for k, o in zip(geometry.k_n_per_mm, offset, strict=True)
    )
    return max(offset), top
