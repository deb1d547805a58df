"""Phantom file contract, ground-truth queries and the buried-inclusion response."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy import integrate, ndimage
from scipy.special import chndtr

from models.phantom import (
    DEFAULT_CONTACT_RADIUS_MM,
    DomedThickness,
    Phantom,
    PhantomError,
    load_phantom,
    parse_phantom,
)

PHANTOMS = Path(__file__).resolve().parent.parent / "phantoms"
E_BG = 26.4


def _tissue(**over: Any) -> dict[str, Any]:
    data: dict[str, Any] = {"size_mm": [60, 60], "thickness_mm": 10, "youngs_modulus_kpa": E_BG}
    data.update(over)
    return data


def _one(radius: float = 5.0, depth: float = 2.0, ratio: float = 4.0, **over: Any) -> Phantom:
    inc = {
        "center_mm": [30, 30],
        "radius_mm": radius,
        "depth_mm": depth,
        "youngs_modulus_kpa": ratio * E_BG,
    }
    return parse_phantom(_tissue(inclusions=[inc], **over), "t")


# ------------------------------------------------------------------ the contract


def test_design_md_example_parses_verbatim() -> None:
    text = """
size_mm: [60, 60]                # x, y extent
thickness_mm: 20                 # a number, or {center: 4, edge: 2} for a domed top
youngs_modulus_kpa: 26.4         # background tissue
poisson_ratio: 0.5
inclusions:                      # stiff lumps ("tumours"), any number, may be []
  - {center_mm: [15, 15], radius_mm: 4, depth_mm: 2, youngs_modulus_kpa: 158.4}
noise: {displacement_mm: 0.005, pressure_kpa: 0.01, pixel: 0.3}   # optional
"""
    ph = parse_phantom(yaml.safe_load(text), "design")
    assert ph.size_mm == (60.0, 60.0) and ph.thickness_mm == 20.0
    assert ph.inclusions[0].center_mm == (15.0, 15.0) and ph.inclusions[0].height_mm is None
    assert not ph.is_spring_sample


def test_optional_keys_have_documented_defaults() -> None:
    ph = parse_phantom(_tissue(), "t")
    assert ph.poisson_ratio == 0.5 and ph.inclusions == ()
    assert (ph.noise.displacement_mm, ph.noise.pressure_kpa, ph.noise.pixel) == (0.005, 0.01, 0.3)
    partial = parse_phantom(_tissue(noise={"pixel": 1.5}), "t").noise
    assert (partial.displacement_mm, partial.pixel) == (0.005, 1.5)


def test_shipped_phantoms_load_and_match_the_papers() -> None:
    files = sorted(p.name for p in PHANTOMS.glob("*.yaml"))
    for name in ("airfloat_tumours", "flat_26k", "flat_10k", "flat_26k_tumours"):
        assert f"{name}.yaml" in files
    air = load_phantom(PHANTOMS / "airfloat_tumours.yaml")
    assert air.thickness_mm == DomedThickness(center=4.0, edge=2.0)
    assert air.youngs_modulus_kpa == 26.4 and len(air.inclusions) == 4
    ratios = [inc.youngs_modulus_kpa / 26.4 for inc in air.inclusions]  # type: ignore[operator]
    assert max(ratios) == pytest.approx(6.0) and all(inc.depth_mm == 2.0 for inc in air.inclusions)
    assert (
        sum(inc.radius_mm >= 4 and q >= 2 for inc, q in zip(air.inclusions, ratios, strict=True))
        >= 3
    )
    for flat, e in (("flat_26k", 26.4), ("flat_10k", 10.8)):
        ph = load_phantom(PHANTOMS / f"{flat}.yaml")
        assert (ph.thickness_mm, ph.youngs_modulus_kpa, ph.inclusions) == (20.0, e, ())
    for tag, k in (("029", 0.29), ("037", 0.37), ("062", 0.62), ("063", 0.63)):
        ph = load_phantom(PHANTOMS / f"springs_{tag}.yaml")
        assert ph.is_spring_sample and ph.spring_constant(20.0, 20.0) == k
    cam = load_phantom(PHANTOMS / "flat_26k_tumours.yaml")
    assert cam.thickness_mm == 10.0 and len(cam.inclusions) == 3
    for inc in cam.inclusions:
        ratio = inc.youngs_modulus_kpa / 26.4  # type: ignore[operator]
        assert 4 <= inc.radius_mm <= 6 and 2 <= ratio <= 5 and inc.depth_mm == 2


def _write(tmp_path: Path, data: Any) -> Path:
    path = tmp_path / "x.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


_INC = {"center_mm": [30, 30], "radius_mm": 4, "depth_mm": 2, "youngs_modulus_kpa": 100}
ERROR_CASES: list[tuple[str, dict[str, Any], int, str]] = [
    # (what, data, line of the offending key in yaml.safe_dump's layout, the message after file:line:col)
    ("unknown top key", _tissue(colour="red"), 6, "unknown key 'colour' in the phantom; expected one of: size_mm"),
    ("unknown inclusion key", _tissue(inclusions=[_INC, {**_INC, "shape": "ball"}]), 17,
     "unknown key 'shape' in inclusions[1]"),
    ("unknown noise key", _tissue(noise={"pixels": 1}), 7, "unknown key 'pixels' in noise (did you mean 'pixel'?)"),
    ("missing thickness", {"size_mm": [60, 60], "youngs_modulus_kpa": 1}, 1,
     "the phantom is missing the required key 'thickness_mm'"),
    ("missing dome edge", _tissue(thickness_mm={"center": 4}), 5, "thickness_mm is missing the required key 'edge'"),
    ("missing inclusion depth", _tissue(inclusions=[{k: v for k, v in _INC.items() if k != "depth_mm"}]), 7,
     "inclusions[0] is missing the required key 'depth_mm'"),
    ("negative radius", _tissue(inclusions=[{**_INC, "radius_mm": -1}]), 10,
     "inclusions[0].radius_mm: expected `float` > 0.0, got -1"),
    ("string thickness", _tissue(thickness_mm="4"), 4, "thickness_mm: expected `float | object`, got `str`"),
    ("bool modulus", _tissue(youngs_modulus_kpa=True), 5, "youngs_modulus_kpa: expected `float | null`, got `bool`"),
    ("three sizes", _tissue(size_mm=[60, 60, 3]), 2, "size_mm: expected `array` of length 2, got 3"),
    ("poisson too big", _tissue(poisson_ratio=0.6), 6, "poisson_ratio: expected `float` <= 0.5, got 0.6"),
    ("negative noise", _tissue(noise={"pressure_kpa": -0.1}), 7, "noise.pressure_kpa: expected `float` >= 0.0"),
    ("infinite modulus", _tissue(youngs_modulus_kpa=float("inf")), 5,
     "youngs_modulus_kpa: must be a finite number, got inf"),
    ("both materials", _tissue(spring_constant_n_per_mm=0.3), 5,
     "youngs_modulus_kpa: give exactly one of youngs_modulus_kpa (tissue) or spring_constant_n_per_mm"),
    ("no material", {"size_mm": [60, 60], "thickness_mm": 10}, 1, "youngs_modulus_kpa: give exactly one of"),
    ("spring inclusion in tissue", _tissue(inclusions=[{**_INC, "spring_constant_n_per_mm": 1}]), 13,
     "inclusions[0].spring_constant_n_per_mm: not allowed in a phantom that uses youngs_modulus_kpa"),
    ("inclusion without modulus", _tissue(inclusions=[{k: v for k, v in _INC.items() if k != "youngs_modulus_kpa"}]),
     7, "inclusions[0].youngs_modulus_kpa: required key missing"),
    ("centre off the phantom", _tissue(inclusions=[{**_INC, "center_mm": [70, 30]}]), 8,
     "inclusions[0].center_mm: must lie inside the footprint [0, 60.0] x [0, 60.0] mm, got [70.0, 30.0]"),
    ("inclusions not a list", _tissue(inclusions={"a": 1}), 7, "inclusions: expected `array`, got `object`"),
]


@pytest.mark.parametrize(("what", "data", "line", "message"), ERROR_CASES, ids=[c[0] for c in ERROR_CASES])
def test_invalid_files_name_file_line_and_key(
    tmp_path: Path, what: str, data: dict[str, Any], line: int, message: str
) -> None:
    path = _write(tmp_path, data)
    with pytest.raises(PhantomError) as info:
        load_phantom(path)
    err = info.value
    assert isinstance(err, ValueError)
    assert re.match(rf"{re.escape(str(path))}:{line}:\d+: {re.escape(message)}", str(err)), str(err)


def test_a_mapping_built_by_a_program_is_named_by_its_source_without_a_line() -> None:
    with pytest.raises(PhantomError) as info:
        parse_phantom(_tissue(poisson_ratio=0.6), "generated #3")
    assert str(info.value) == "generated #3: poisson_ratio: expected `float` <= 0.5, got 0.6"


def test_depth_error_message_matches_the_contract_and_line(tmp_path: Path) -> None:
    text = (
        "size_mm: [60, 60]\n"
        "thickness_mm: {center: 4, edge: 2}\n"
        "youngs_modulus_kpa: 26.4\n"
        "inclusions:\n"
        "  - {center_mm: [15, 30], radius_mm: 4, depth_mm: 2, youngs_modulus_kpa: 52.8}\n"
        "  - center_mm: [45, 30]\n"
        "    radius_mm: 4\n"
        "    depth_mm: 5\n"
        "    youngs_modulus_kpa: 52.8\n"
    )
    path = tmp_path / "dome.yaml"
    path.write_text(text)
    with pytest.raises(PhantomError) as info:
        load_phantom(path)
    assert str(info.value) == (
        f"{path}:8:15: inclusions[1].depth_mm: must be less than the local thickness 4.0 mm, got 5.0"
    )


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(PhantomError, match=r"missing\.yaml: cannot read"):
        load_phantom(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("size_mm: [60, 60\nthickness_mm: 4\n")
    with pytest.raises(PhantomError, match=r"bad\.yaml:\d+:\d+: invalid YAML"):
        load_phantom(bad)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(PhantomError, match=r"bad\.yaml:1:1: expected a mapping at the top level, got list"):
        load_phantom(bad)
    bad.write_text("size_mm: [60, 60]\nthickness_mm: 4\nthickness_mm: 5\nyoungs_modulus_kpa: 1\n")
    with pytest.raises(PhantomError, match=r"bad\.yaml:3:1: duplicate key 'thickness_mm' \(first at line 2\)"):
        load_phantom(bad)


# ------------------------------------------------------------------ geometry and ground truth


def test_domed_profile_is_a_smooth_parabola_along_y() -> None:
    ph = load_phantom(PHANTOMS / "airfloat_tumours.yaml")
    assert ph.thickness(30.0, 30.0) == pytest.approx(4.0)
    assert ph.thickness(30.0, 0.0) == pytest.approx(2.0) and ph.thickness(
        5.0, 60.0
    ) == pytest.approx(2.0)
    assert ph.thickness(30.0, 15.0) == pytest.approx(2.0 + 2.0 * 0.75)
    y = np.linspace(0, 60, 121)
    t = np.asarray(ph.thickness(np.full_like(y, 12.0), y))
    np.testing.assert_allclose(t, t[::-1])  # symmetric about the centre line
    np.testing.assert_allclose(np.diff(t, 2), np.diff(t, 2)[0], atol=1e-12)  # constant curvature
    np.testing.assert_allclose(ph.thickness(np.linspace(0, 60, 7), 20.0), ph.thickness(30.0, 20.0))
    np.testing.assert_array_equal(ph.surface_z(np.array([-1.0, 61.0]), 30.0), [0.0, 0.0])
    assert isinstance(ph.surface_z(1.0, 2.0), float)


def test_youngs_modulus_field_and_inclusion_lookup() -> None:
    inc = {**_INC, "height_mm": 3.0}
    ph = parse_phantom(_tissue(inclusions=[inc, {**_INC, "center_mm": [10, 10]}]), "t")
    e = np.asarray(
        ph.youngs_modulus(30.0, 30.0, np.array([0.0, 1.9, 2.0, 5.0, 5.1, 10.0, 10.1, -0.1]))
    )
    np.testing.assert_array_equal(e[:6], [E_BG, E_BG, 100, 100, E_BG, E_BG])
    assert np.isnan(e[6:]).all()  # below the table, above the surface
    assert np.asarray(ph.youngs_modulus(10.0, 10.0, 9.9)) == 100  # no height: down to the table
    assert math.isnan(ph.youngs_modulus(-1.0, 30.0))
    assert ph.inclusion_at(30.0, 33.9) == 0 and ph.inclusion_at(30.0, 34.1) == -1
    np.testing.assert_array_equal(
        ph.inclusion_at(np.array([10.0, 50.0, 30.0]), np.array([10.0, 50.0, 30.0])), [1, -1, 0]
    )


# ------------------------------------------------------------------ effective modulus


def test_far_from_inclusions_the_background_is_recovered() -> None:
    ph = _one()
    assert ph.effective_modulus(5.0, 55.0, 4.0, 1.0) == pytest.approx(E_BG, rel=1e-4)
    flat = parse_phantom(_tissue(), "t")
    assert flat.effective_modulus(30.0, 30.0, 4.0, 1.0) == E_BG
    assert math.isnan(ph.effective_modulus(61.0, 30.0, 4.0, 1.0))
    # An indenter pushed to the table has no tissue bulb left: defined as the background.
    assert ph.effective_modulus(30.0, 30.0, 4.0, 10.0) == E_BG


def test_lateral_response_is_symmetric_peaked_and_bounded() -> None:
    ph = _one()
    ring = [
        ph.effective_modulus(30 + 3 * math.cos(a), 30 + 3 * math.sin(a), 4.0, 1.0)
        for a in np.linspace(0, 6, 7)
    ]
    np.testing.assert_allclose(ring, ring[0], rtol=1e-12)
    dx = np.linspace(0.0, 20.0, 41)
    e = np.asarray(ph.effective_modulus(30.0 + dx, 30.0, 4.0, 1.0))
    assert np.all(np.diff(e) < 0) and E_BG < e[-1] < e[0] < 4 * E_BG
    e_neg = np.asarray(ph.effective_modulus(30.0 - dx, 30.0, 4.0, 1.0))
    np.testing.assert_allclose(e, e_neg, rtol=1e-12)


def test_contrast_falls_with_depth_ratio_and_size() -> None:
    def contrast(**kw: Any) -> float:
        return _one(**kw).effective_modulus(30.0, 30.0, 4.0, 1.0) / E_BG - 1.0

    by_depth = [contrast(depth=z) for z in (1.0, 1.5, 2.0, 3.0, 5.0, 8.0)]
    by_ratio = [contrast(ratio=q) for q in (6.0, 4.0, 2.0, 1.5)]
    by_size = [contrast(radius=r) for r in (8.0, 6.0, 4.0, 3.0, 2.0, 1.0)]
    for series in (by_depth, by_ratio, by_size):
        assert all(a > b > 0 for a, b in zip(series, series[1:], strict=False)), series
    assert contrast(ratio=0.5) < 0  # a soft inclusion reads softer
    # Pressing deeper brings a buried inclusion closer to the stress bulb.
    ph = _one(depth=3.0)
    assert ph.effective_modulus(30.0, 30.0, 4.0, 2.0) > ph.effective_modulus(30.0, 30.0, 4.0, 0.5)


def test_bulb_fraction_quadrature_matches_adaptive_integration() -> None:
    ph = _one(radius=4.0, depth=2.0, ratio=3.0)
    x, y, c, d = 33.0, 31.0, 2.0, 1.0
    phi = float(ph._bulb_fractions(np.float64(x), np.float64(y), np.float64(c), np.float64(d))[0])
    lat2 = 3.0**2 + 1.0**2

    def dens(z: float) -> float:
        return (1 - z**3 / (z * z + c * c) ** 1.5) / (2 * c)

    def lateral(z: float) -> float:
        s2 = c * c / 4 + z * z
        # fraction of an isotropic 2-D Gaussian inside the disc, by direct polar integration
        inner = integrate.dblquad(
            lambda rho, th: (
                rho
                * math.exp(-(rho**2 + lat2 - 2 * rho * math.sqrt(lat2) * math.cos(th)) / (2 * s2))
            ),
            0,
            2 * math.pi,
            0,
            4.0,
        )[0]
        return inner / (2 * math.pi * s2)

    z_max = 10.0 - d
    norm = integrate.quad(dens, 0, z_max)[0]
    num = integrate.quad(lambda z: dens(z) * lateral(z), 2.0 - d, z_max, limit=50, epsabs=1e-7)[0]
    assert phi == pytest.approx(num / norm, rel=2e-4)
    # the closed form used for the lateral weight: a non-central chi-square CDF with 2 dof
    s2 = c * c / 4 + 1.0
    assert chndtr(16.0 / s2, 2, lat2 / s2) == pytest.approx(lateral(1.0), rel=1e-7)


def test_raster_scan_finds_inclusions_with_centroids_within_1mm() -> None:
    for name, depth in (("airfloat_tumours", 1.0), ("flat_26k_tumours", 1.0)):
        ph = load_phantom(PHANTOMS / f"{name}.yaml")
        axis = np.arange(0.0, 60.01, 1.0)
        xg, yg = np.meshgrid(axis, axis)
        contrast = (
            np.asarray(ph.effective_modulus(xg, yg, 4.0, depth)) / ph.youngs_modulus_kpa - 1.0
        )  # type: ignore[operator]
        labels, _ = ndimage.label(contrast > 0.15)
        for inc in ph.inclusions:
            ratio = inc.youngs_modulus_kpa / ph.youngs_modulus_kpa  # type: ignore[operator]
            if inc.radius_mm < 4 or ratio < 2:
                continue
            cx, cy = inc.center_mm
            blob = labels == labels[int(round(cy)), int(round(cx))]
            assert labels[int(round(cy)), int(round(cx))] > 0, (name, inc)
            w = contrast * blob
            found = ((w * xg).sum() / w.sum(), (w * yg).sum() / w.sum())
            assert math.dist(found, (cx, cy)) < 1.0, (name, inc, found)
    # "less clear as stiffness ratio and size decrease": the peaks rank accordingly.
    air = load_phantom(PHANTOMS / "airfloat_tumours.yaml")
    peaks = [air.effective_modulus(*inc.center_mm, 4.0, 1.0) for inc in air.inclusions]
    assert peaks[0] > peaks[1] > peaks[2]  # (r 6, x6) > (r 5, x4) > (r 4, x2)


# ------------------------------------------------------------------ spring constants


def test_spring_constant_of_tissue_is_a_flat_punch_and_scales_with_stiffness() -> None:
    flat = parse_phantom(_tissue(), "t")
    a = DEFAULT_CONTACT_RADIUS_MM
    assert flat.spring_constant(30.0, 30.0) == pytest.approx(2 * a * 0.0264 / 0.75)
    assert flat.spring_constant(30.0, 30.0, contact_radius_mm=3.0) == pytest.approx(
        3 * 0.0264 / 0.75 * 2
    )
    ph = _one(depth=0.0, radius=20.0, ratio=4.0)  # a huge inclusion reaching the surface
    # ... is felt almost fully (K_t proportional to E): 4x the background within 1 %.
    assert ph.spring_constant(30.0, 30.0) / flat.spring_constant(30.0, 30.0) == pytest.approx(
        4.0, rel=0.01
    )
    buried = _one()
    k_far = buried.spring_constant(45.0, 45.0)
    assert buried.spring_constant(30.0, 30.0) > 1.5 * k_far
    assert k_far == pytest.approx(flat.spring_constant(0.0, 0.0), rel=0.01)


def test_spring_sample_queries() -> None:
    data = {
        "size_mm": [40, 40],
        "thickness_mm": 30,
        "spring_constant_n_per_mm": 0.29,
        "inclusions": [
            {"center_mm": [10, 10], "radius_mm": 3, "depth_mm": 0, "spring_constant_n_per_mm": 0.63}
        ],
    }
    ph = parse_phantom(data, "s")
    k = np.asarray(ph.spring_constant(np.array([10.0, 20.0, 50.0]), np.array([10.0, 20.0, 20.0])))
    np.testing.assert_array_equal(k[:2], [0.63, 0.29])
    assert np.isnan(k[2])
    with pytest.raises(ValueError, match="spring sample, use spring_constant"):
        ph.effective_modulus(10.0, 10.0, 4.0, 1.0)
    with pytest.raises(PhantomError, match=r"s: inclusions\[0\]\.youngs_modulus_kpa: not allowed"):
        parse_phantom(
            {**data, "inclusions": [{**data["inclusions"][0], "youngs_modulus_kpa": 5}]}, "s"
        )  # type: ignore[dict-item]
