"""Air-float stiffness probe: indentation geometry (paper eqs. 1-3) and force calibration (eq. 4).

Probe frame (paper Fig. 4): origin O at the centre of the probe face, x-y in the face, z along
the probe axis pointing *out of the face towards the tissue*. The three surface profile sensor
(SPS) tips sit on a circle of radius a at
    D3 = (0, a, h1),  D2 = (-a*sqrt3/2, -a/2, h2),  D1 = (a*sqrt3/2, -a/2, h3)
(the paper's pairing of h1 with D3 is kept), and h4 is the extension of the deepest point of the
spherical indenter S1 (radius r) along the axis. All lengths in mm, angles in radians.

Defaults (the paper gives no single number for either):
- ``DEFAULT_INDENTER_RADIUS_MM = 4.0``: the paper's "d/r = 5" for its 20 mm samples implies
  r = 4 mm (its CFD used 7.0 and 7.6 mm indenters in an 8 mm bore, i.e. r = 3.5-3.8 mm).
- ``DEFAULT_SPS_RADIUS_MM = 6.0``: the SPS ring lies outside the 8 mm bore; 6 mm assumes ~2 mm
  walls. Only the estimator and the simulator need to agree on it.

All functions accept floats or numpy arrays (broadcast together).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, NamedTuple

import numpy as np

from models._arrays import ArrayLike, FloatArray
from models._arrays import as_f64 as _f64
from models._arrays import scalar_or_array as _out

if TYPE_CHECKING:
    from models.phantom import Phantom


DEFAULT_INDENTER_RADIUS_MM = 4.0
DEFAULT_SPS_RADIUS_MM = 6.0
_SQRT3 = float(np.sqrt(3.0))




def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"airfloat: {name} must be finite and > 0 (mm), got {value!r}")


class ProbeHeights(NamedTuple):
    """Extensions (mm) of SPS1..3 (h1 at D3, h2 at D2, h3 at D1) and the indenter tip (h4)."""

    h1: ArrayLike
    h2: ArrayLike
    h3: ArrayLike
    h4: ArrayLike


def sps_positions(a: float = DEFAULT_SPS_RADIUS_MM) -> FloatArray:
    """(3, 2) array of the probe-frame x, y (mm) of the SPS tips carrying h1, h2, h3 (D3, D2, D1)."""
    _check_positive("a", a)
    return np.array([[0.0, a], [-a * _SQRT3 / 2, -a / 2], [a * _SQRT3 / 2, -a / 2]])


def surface_plane_from_heights(
    h1: ArrayLike, h2: ArrayLike, h3: ArrayLike, a: float = DEFAULT_SPS_RADIUS_MM
) -> tuple[ArrayLike, ArrayLike, ArrayLike]:
    """The plane D1D2D3 under the probe: (d_n, theta_z, azimuth).

    d_n (mm) is the normal distance from the probe face centre to the plane (eq. 2), theta_z the
    angle between the probe axis and the plane normal (eq. 3), azimuth the direction (rad, from the
    probe +x towards +y) in which the plane normal leans, i.e. the plane falls away (its h grows)
    towards azimuth + pi. theta_z is computed as atan2(sqrt(S), 3a), which equals eq. 3's
    arccos(3a / sqrt(S + 9a^2)) but keeps full precision at small tilt.
    """
    _check_positive("a", a)
    h1a, h2a, h3a = _f64(h1), _f64(h2), _f64(h3)
    s = 2.0 * ((h2a - h1a) ** 2 + (h3a - h1a) ** 2 + (h3a - h2a) ** 2)
    root = np.sqrt(s + 9.0 * a * a)
    d_n = a * (h1a + h2a + h3a) / root  # eq. 2
    theta = np.arctan2(np.sqrt(s), 3.0 * a)  # eq. 3
    # The plane is z = alpha + beta x + gamma y with these slopes (the SPS layout is orthogonal);
    # its normal (-beta, -gamma, 1) leans towards atan2(-gamma, -beta).
    beta = (h3a - h2a) / (a * _SQRT3)
    gamma = (2.0 * h1a - h2a - h3a) / (3.0 * a)
    azimuth = np.arctan2(-gamma, -beta)
    return _out(d_n, h1, h2, h3), _out(theta, h1, h2, h3), _out(azimuth, h1, h2, h3)


def surface_distance(h1: float, h2: float, h3: float, a: float = DEFAULT_SPS_RADIUS_MM) -> float:
    """Eq. 2's d_n (mm) for one sample of plain floats: :func:`surface_plane_from_heights`'s first output to the
    bit (the same operations in the same order; numpy's 0-d arithmetic costs ~20x more, and a probe following
    the surface asks 500 times a simulated second)."""
    _check_positive("a", a)
    s = 2.0 * ((h2 - h1) ** 2 + (h3 - h1) ** 2 + (h3 - h2) ** 2)  # pow(), as numpy's scalars (not x * x)
    return a * (h1 + h2 + h3) / math.sqrt(s + 9.0 * a * a)


def indentation_from_heights(
    h1: ArrayLike,
    h2: ArrayLike,
    h3: ArrayLike,
    h4: ArrayLike,
    a: float = DEFAULT_SPS_RADIUS_MM,
    r: float = DEFAULT_INDENTER_RADIUS_MM,
) -> tuple[ArrayLike, ArrayLike]:
    """Absolute indentation depth d_in (mm) and tilt theta_z (rad) from the four extensions, eqs. 1-3.

    d_in = r - d_n - (r - h4) cos(theta_z): how far the indenter sphere reaches beyond the SPS
    plane, measured along the plane normal. Negative means the indenter is clear of the surface.
    """
    _check_positive("r", r)
    d_n, theta, _ = surface_plane_from_heights(h1, h2, h3, a)
    d_in = r - _f64(d_n) - (r - _f64(h4)) * np.cos(_f64(theta))  # eq. 1
    return _out(d_in, h1, h2, h3, h4), theta


def heights_from_pose(
    height_mm: ArrayLike,
    tilt_rad: ArrayLike,
    azimuth_rad: ArrayLike,
    depth_mm: ArrayLike,
    a: float = DEFAULT_SPS_RADIUS_MM,
    r: float = DEFAULT_INDENTER_RADIUS_MM,
) -> ProbeHeights:
    """Forward of eqs. 1-3: extensions h1..h4 (mm) for a probe over a locally flat surface.

    height_mm: distance from the face centre to the surface plane along the probe axis;
    tilt_rad: angle between probe axis and surface normal (theta_z), must be in [0, pi/2);
    azimuth_rad: direction (probe frame, from +x towards +y) the surface normal leans to;
    depth_mm: indentation of the sphere beyond the plane along its normal (d_in).
    ``indentation_from_heights`` inverts this exactly (to rounding).
    """
    _check_positive("a", a)
    _check_positive("r", r)
    tilt = _f64(tilt_rad)
    if np.any(~np.isfinite(tilt) | (tilt < 0) | (tilt >= np.pi / 2)):
        raise ValueError(f"airfloat: tilt_rad must be in [0, pi/2), got {tilt_rad!r}")
    height, az, d = _f64(height_mm), _f64(azimuth_rad), _f64(depth_mm)
    cos_t, tan_t = np.cos(tilt), np.tan(tilt)
    xy = sps_positions(a)
    hs = [height - tan_t * (np.cos(az) * x + np.sin(az) * y) for x, y in xy]
    d_n = height * cos_t
    h4 = r - (r - d_n - d) / cos_t  # eq. 1 solved for h4
    args = (height_mm, tilt_rad, azimuth_rad, depth_mm)
    return ProbeHeights(*(_out(np.asarray(h), *args) for h in (*hs, h4)))


def _probe_rotation(tilt: FloatArray, azimuth: FloatArray) -> FloatArray:
    """World-from-probe rotations, shape (..., 3, 3), for a probe pointing down, then tilted.

    Untilted: probe x = world x, probe y = world -y, probe z (outward axis) = world -z. Tilting
    rotates about the horizontal world axis k = (sin az, -cos az, 0) so the outward axis becomes
    (sin t cos az, sin t sin az, -cos t): the tip leans towards world azimuth az.
    """
    kx, ky = np.sin(azimuth), -np.cos(azimuth)
    c, s = np.cos(tilt), np.sin(tilt)
    zero = np.zeros_like(c)
    # Rodrigues for a unit axis with kz = 0.
    rot = np.stack(
        [
            np.stack([c + kx * kx * (1 - c), kx * ky * (1 - c), ky * s], -1),
            np.stack([kx * ky * (1 - c), c + ky * ky * (1 - c), -kx * s], -1),
            np.stack([-ky * s, kx * s, c + zero], -1),
        ],
        -2,
    )
    down = np.diag([1.0, -1.0, -1.0])
    out: FloatArray = rot @ down
    return out


def _axis_hit(
    phantom: Phantom, start: FloatArray, u: FloatArray, cos_t: FloatArray, iters: int = 60
) -> FloatArray:
    """Distance t >= 0 along the unit direction u from start (..., 3) to the phantom surface.

    Fixed point t = (z0 - surface(xy0 + t u_xy)) / cos(tilt): exact in one step for a vertical
    probe; contracts whenever the surface slope times tan(tilt) is below 1.
    """
    t = (start[..., 2] - _f64(phantom.surface_z(start[..., 0], start[..., 1]))) / cos_t
    for _ in range(iters):
        x = start[..., 0] + t * u[..., 0]
        y = start[..., 1] + t * u[..., 1]
        t_new = (start[..., 2] - _f64(phantom.surface_z(x, y))) / cos_t
        if np.all(np.abs(t_new - t) < 1e-12):
            return t_new
        t = t_new
    return t


def heights_over_phantom(
    phantom: Phantom,
    x_mm: ArrayLike,
    y_mm: ArrayLike,
    z_face_mm: ArrayLike,
    depth_mm: ArrayLike,
    a: float = DEFAULT_SPS_RADIUS_MM,
    r: float = DEFAULT_INDENTER_RADIUS_MM,
    tilt_rad: ArrayLike = 0.0,
    azimuth_rad: ArrayLike = 0.0,
    depth_reference: Literal["plane", "surface"] = "plane",
) -> ProbeHeights:
    """What the fibre-optic sensors read with the probe face centre at world (x, y, z_face) (mm).

    The probe points down (frame convention in ``_probe_rotation``; optional tilt towards a world
    azimuth). Each SPS extension is the distance along the axis from its face point to the
    phantom surface (found exactly on the curved surface). The indenter tip extension h4 places
    the sphere depth_mm into the tissue:
    - ``depth_reference="plane"`` (default): depth is d_in relative to the plane through the
      three SPS contacts, so eqs. 1-3 recover depth_mm exactly;
    - ``"surface"``: depth is measured along the axis from the true surface point under the
      indenter, so on a curved top eqs. 1-3 see the plane-versus-surface error a real probe has.
    Nothing is clamped: a negative h means the face is below the surface (a collision the caller
    must catch), and h4 may exceed the indenter's travel.
    """
    _check_positive("a", a)
    _check_positive("r", r)
    x, y, zf, d = np.broadcast_arrays(_f64(x_mm), _f64(y_mm), _f64(z_face_mm), _f64(depth_mm))
    tilt = np.broadcast_to(_f64(tilt_rad), x.shape)
    if np.any(~np.isfinite(tilt) | (tilt < 0) | (tilt >= np.pi / 2)):
        raise ValueError(f"airfloat: tilt_rad must be in [0, pi/2), got {tilt_rad!r}")
    az = np.broadcast_to(_f64(azimuth_rad), x.shape)
    rot = _probe_rotation(tilt, az)
    u = rot[..., :, 2]
    cos_t = np.cos(tilt)
    centre = np.stack([x, y, zf], -1)
    hs = []
    for px, py in sps_positions(a):
        face_pt = centre + rot @ np.array([px, py, 0.0])
        hs.append(_axis_hit(phantom, face_pt, u, cos_t))
    h1, h2, h3 = hs
    if depth_reference == "plane":
        d_n, theta, _ = surface_plane_from_heights(h1, h2, h3, a)
        h4 = r - (r - _f64(d_n) - d) / np.cos(_f64(theta))
    elif depth_reference == "surface":
        h4 = _axis_hit(phantom, centre, u, cos_t) + d
    else:
        raise ValueError(
            f"airfloat: depth_reference must be 'plane' or 'surface', got {depth_reference!r}"
        )
    args = (x_mm, y_mm, z_face_mm, depth_mm, tilt_rad, azimuth_rad)
    return ProbeHeights(*(_out(np.asarray(h), *args) for h in (h1, h2, h3, h4)))


@dataclass(frozen=True)
class ForceCalibration:
    """Indentation force from the probe's internal air pressure, eq. 4: F = gain * P + offset.

    Units (the paper states none): F in N and P in units of ``pressure_unit_kpa`` (default
    100 kPa, i.e. bar); methods take and return kPa. Why bar: with P in bar the force is zero at
    0.308 bar = 30.8 kPa, which matches the paper's 30 kPa supply set-point, and its ~0.6 N
    indentation of a 26 kPa sample to 3 mm needs ~39 kPa. Read as kPa instead, 30 kPa would give
    225 N. Set ``pressure_unit_kpa=1.0`` to read the paper literally in kPa.
    """

    gain: float = 7.59  # N per pressure unit
    offset: float = -2.34  # N
    pressure_unit_kpa: float = 100.0

    def __post_init__(self) -> None:
        for name in ("gain", "pressure_unit_kpa"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ForceCalibration: {name} must be finite and > 0, got {value!r}")
        if not np.isfinite(self.offset):
            raise ValueError(f"ForceCalibration: offset must be finite, got {self.offset!r}")

    @property
    def contact_pressure_kpa(self) -> float:
        """Pressure (kPa) at which the calibrated force reaches zero: below it F is clamped to 0."""
        return -self.offset / self.gain * self.pressure_unit_kpa

    def force_n(self, pressure_kpa: ArrayLike) -> ArrayLike:
        """Indentation force (N) at internal pressure (kPa), clamped to >= 0 (no pulling force)."""
        p = _f64(pressure_kpa) / self.pressure_unit_kpa
        return _out(np.clip(self.gain * p + self.offset, 0.0, None), pressure_kpa)

    def pressure_kpa(self, force_n: ArrayLike) -> ArrayLike:
        """Internal pressure (kPa) that yields force (N); F <= 0 maps to ``contact_pressure_kpa``.

        Never negative: with a positive offset, forces below it are unreachable and map to 0 kPa.
        """
        f = np.clip(_f64(force_n), 0.0, None)
        p = np.clip((f - self.offset) / self.gain * self.pressure_unit_kpa, 0.0, None)
        return _out(p, force_n)
