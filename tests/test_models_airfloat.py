"""Air-float probe geometry (eqs. 1-3, both directions) and the pressure-force calibration (eq. 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from models.airfloat import (
    DEFAULT_INDENTER_RADIUS_MM,
    DEFAULT_SPS_RADIUS_MM,
    ForceCalibration,
    ProbeHeights,
    _probe_rotation,
    heights_from_pose,
    heights_over_phantom,
    indentation_from_heights,
    sps_positions,
    surface_distance,
    surface_plane_from_heights,
)
from models.phantom import Phantom, parse_phantom

A, RR = DEFAULT_SPS_RADIUS_MM, DEFAULT_INDENTER_RADIUS_MM


def _flat(thickness: float = 20.0) -> Phantom:
    return parse_phantom(
        {"size_mm": [60, 60], "thickness_mm": thickness, "youngs_modulus_kpa": 26.4}
    )


def _dome() -> Phantom:
    return parse_phantom(
        {"size_mm": [60, 60], "thickness_mm": {"center": 4, "edge": 2}, "youngs_modulus_kpa": 26.4}
    )


def test_sps_positions_are_the_papers_fig4_layout() -> None:
    xy = sps_positions(6.0)
    s3 = math.sqrt(3)
    np.testing.assert_allclose(xy, [[0, 6], [-6 * s3 / 2, -3], [6 * s3 / 2, -3]], atol=1e-15)
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1]), 6.0)
    np.testing.assert_allclose(xy.sum(axis=0), 0.0, atol=1e-14)
    assert DEFAULT_INDENTER_RADIUS_MM == 4.0


def test_flat_square_probe_reads_height_and_depth_directly() -> None:
    d_in, theta = indentation_from_heights(3.0, 3.0, 3.0, 4.25)
    assert d_in == pytest.approx(1.25, abs=1e-15) and theta == 0.0
    h = heights_from_pose(3.0, 0.0, 0.0, 1.25)
    assert h == ProbeHeights(3.0, 3.0, 3.0, 4.25)


def _eq3_literal(h1: float, h2: float, h3: float, a: float) -> float:
    s = 2 * ((h2 - h1) ** 2 + (h3 - h1) ** 2 + (h3 - h2) ** 2)
    return math.acos(min(3 * a / math.sqrt(s + 9 * a * a), 1.0))


def _penetration_by_geometry(h: tuple[float, ...], a: float, r: float) -> tuple[float, float]:
    """Independent 3-D construction: plane through the SPS tips, sphere with its tip at z = h4."""
    pts = np.array([[x, y, hz] for (x, y), hz in zip(sps_positions(a), h[:3], strict=True)])
    n = np.cross(pts[1] - pts[0], pts[2] - pts[0])
    n /= np.linalg.norm(n)
    n *= np.sign(n[2])  # point the normal out of the face, towards the tissue
    d_n = float(n @ pts[0])
    centre = np.array([0.0, 0.0, h[3] - r])
    return r - (d_n - float(n @ centre)), math.atan2(math.hypot(n[0], n[1]), n[2])


@given(
    h=st.tuples(*[st.floats(0.0, 8.0)] * 4),
    a=st.floats(3.0, 10.0),
    r=st.floats(2.0, 6.0),
)
def test_eqs_1_to_3_match_a_direct_3d_construction(
    h: tuple[float, float, float, float], a: float, r: float
) -> None:
    d_in, theta = indentation_from_heights(*h, a=a, r=r)
    d_geo, theta_geo = _penetration_by_geometry(h, a, r)
    assert d_in == pytest.approx(d_geo, abs=1e-9)
    assert theta == pytest.approx(theta_geo, abs=1e-9)
    assert theta == pytest.approx(_eq3_literal(*h[:3], a), abs=1e-7)  # acos: ~1e-8 near 0


@given(
    height=st.floats(0.5, 20.0),
    tilt=st.floats(0.0, math.radians(30)),
    azimuth=st.floats(-math.pi, math.pi),
    depth=st.floats(0.0, 5.0),
    a=st.floats(3.0, 10.0),
    r=st.floats(2.0, 6.0),
)
def test_forward_then_inverse_round_trips_to_1e_9(
    height: float, tilt: float, azimuth: float, depth: float, a: float, r: float
) -> None:
    h = heights_from_pose(height, tilt, azimuth, depth, a=a, r=r)
    d_in, theta = indentation_from_heights(*h, a=a, r=r)
    assert d_in == pytest.approx(depth, abs=1e-9)
    assert theta == pytest.approx(tilt, abs=1e-9)
    d_n, _, az = surface_plane_from_heights(h.h1, h.h2, h.h3, a=a)
    assert d_n == pytest.approx(height * math.cos(tilt), abs=1e-9)
    if tilt > 1e-3:
        assert math.remainder(az - azimuth, 2 * math.pi) == pytest.approx(0.0, abs=1e-6)


def test_vectorised_over_arrays() -> None:
    rng = np.random.default_rng(2)
    n = 1000
    depth = rng.uniform(0, 3, n)
    tilt = rng.uniform(0, 0.5, n)
    h = heights_from_pose(rng.uniform(1, 5, n), tilt, rng.uniform(-3, 3, n), depth)
    d_in, theta = indentation_from_heights(*h)
    assert isinstance(d_in, np.ndarray) and d_in.shape == (n,)
    np.testing.assert_allclose(d_in, depth, atol=1e-9)
    np.testing.assert_allclose(theta, tilt, atol=1e-9)
    assert isinstance(indentation_from_heights(1.0, 1.0, 1.0, 1.5)[0], float)


def test_tilt_out_of_range_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"tilt_rad must be in \[0, pi/2\)"):
        heights_from_pose(1.0, math.pi / 2, 0.0, 1.0)
    with pytest.raises(ValueError, match="a must be finite and > 0"):
        sps_positions(0.0)


@given(tilt=st.floats(0.0, 1.2), az=st.floats(-math.pi, math.pi))
def test_probe_rotation_is_proper_and_points_where_documented(tilt: float, az: float) -> None:
    rot = _probe_rotation(np.float64(tilt), np.float64(az))
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    expected_axis = [math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)]
    np.testing.assert_allclose(rot[:, 2], expected_axis, atol=1e-12)


def test_vertical_probe_over_flat_phantom() -> None:
    h = heights_over_phantom(_flat(20.0), 30.0, 30.0, 23.0, 1.5)
    assert h == pytest.approx((3.0, 3.0, 3.0, 4.5))
    h = heights_over_phantom(_flat(20.0), np.array([10.0, 50.0]), 30.0, 22.0, 0.5)
    np.testing.assert_allclose(np.asarray(h.h4), [2.5, 2.5])


def test_tilted_probe_over_flat_phantom_recovers_depth_and_tilt() -> None:
    tilt = math.radians(25)
    h = heights_over_phantom(_flat(20.0), 30.0, 30.0, 24.0, 1.2, tilt_rad=tilt, azimuth_rad=0.7)
    d_in, theta = indentation_from_heights(*h)
    assert d_in == pytest.approx(1.2, abs=1e-9)
    assert theta == pytest.approx(tilt, abs=1e-9)
    # Along-axis distance from the face centre to the table-parallel surface is 4 / cos(tilt).
    d_n, _, _ = surface_plane_from_heights(h.h1, h.h2, h.h3)
    assert d_n == pytest.approx(4.0, abs=1e-9)


@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_sps_contacts_lie_on_the_curved_surface(tilt: float) -> None:
    dome = _dome()
    x, y, zf, az = 30.0, 12.0, 7.0, 1.9
    h = heights_over_phantom(dome, x, y, zf, 1.0, tilt_rad=tilt, azimuth_rad=az)
    rot = _probe_rotation(np.float64(tilt), np.float64(az))
    for (px, py), hi in zip(sps_positions(), (h.h1, h.h2, h.h3), strict=True):
        tip = np.array([x, y, zf]) + rot @ np.array([px, py, float(hi)])
        assert tip[2] == pytest.approx(dome.surface_z(tip[0], tip[1]), abs=1e-9)


def test_dome_plane_reference_is_exact_surface_reference_shows_curvature_error() -> None:
    dome = _dome()
    for y in (10.0, 30.0, 50.0):
        plane = heights_over_phantom(dome, 30.0, y, 6.0, 1.0, depth_reference="plane")
        assert indentation_from_heights(*plane)[0] == pytest.approx(1.0, abs=1e-12)
        true = heights_over_phantom(dome, 30.0, y, 6.0, 1.0, depth_reference="surface")
        d_seen = indentation_from_heights(*true)[0]
        # A convex top rises above the chord plane of the SPS tips: the probe under-reads d.
        assert 0.9 < d_seen < 1.0
    with pytest.raises(ValueError, match="depth_reference"):
        heights_over_phantom(dome, 30.0, 30.0, 6.0, 1.0, depth_reference="tip")  # type: ignore[arg-type]


def test_force_calibration_eq4_with_documented_units() -> None:
    cal = ForceCalibration()
    # F = 7.59 P - 2.34 with P in bar (100 kPa): zero force at ~30.8 kPa, the paper's supply.
    assert cal.contact_pressure_kpa == pytest.approx(2.34 / 7.59 * 100)
    assert cal.force_n(40.0) == pytest.approx(7.59 * 0.4 - 2.34)
    assert cal.force_n(10.0) == 0.0  # clamped: the probe cannot pull
    f = np.asarray(cal.force_n(np.array([0.0, 35.0, 45.0])))
    assert f[0] == 0.0 and f[2] > f[1] > 0
    assert cal.pressure_kpa(cal.force_n(38.5)) == pytest.approx(38.5)
    assert cal.pressure_kpa(0.0) == pytest.approx(cal.contact_pressure_kpa)
    literal = ForceCalibration(pressure_unit_kpa=1.0)
    assert literal.force_n(1.0) == pytest.approx(7.59 - 2.34)


@given(force=st.floats(0.0, 50.0), gain=st.floats(0.1, 20.0), offset=st.floats(-5.0, 5.0))
def test_force_calibration_inverse_round_trips(force: float, gain: float, offset: float) -> None:
    cal = ForceCalibration(gain=gain, offset=offset)
    p = cal.pressure_kpa(force)
    assert p >= 0.0
    # Forces below the zero-pressure force (a positive offset) are unreachable.
    assert cal.force_n(p) == pytest.approx(max(force, offset), abs=1e-9)


def test_force_calibration_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="gain must be finite and > 0"):
        ForceCalibration(gain=0.0)
    with pytest.raises(ValueError, match="offset must be finite"):
        ForceCalibration(offset=float("nan"))


def test_surface_distance_is_eq2s_d_n_to_the_bit() -> None:
    """The follower's scalar d_n (plain floats) is the scalar path of surface_plane_from_heights, bit for bit: a
    last-bit change moves the scan's timeline (x * x for ** 2 differs in ~1 sample in 10 000)."""
    rng = np.random.default_rng(7)
    for h1, h2, h3, a in np.column_stack([rng.uniform(0.0, 10.0, (60_000, 3)),
                                          rng.choice([5.0, 6.0, 6.5], 60_000)]).tolist():
        assert surface_distance(h1, h2, h3, a) == float(surface_plane_from_heights(h1, h2, h3, a)[0])
