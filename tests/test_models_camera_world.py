"""The camera probe's world (models/camera_world.py): springs, friction, stroke and the coupling law, held
against outside mechanics (series springs, Coulomb friction, Boussinesq and the confined thin layer)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.camera_world import (
    CameraWorld,
    ProbeBuild,
    ProbeErrorSpec,
    SpringRods,
    TissueTips,
    layer_deflection_factor,
    layer_kernel,
)
from models.multi_indenter import PAPER_GEOMETRY as G


def ideal() -> ProbeBuild:
    return ProbeBuild.ideal(G.x_mm, G.y_mm, G.k_n_per_mm, 12.7)


def test_rods_and_probe_springs_act_in_series() -> None:
    w = CameraWorld(ideal())
    s = w.press([5.0, 4.0, 3.0, 2.0], SpringRods([0.29] * 4))
    k = np.asarray(G.k_n_per_mm)
    np.testing.assert_allclose(s.dx_mm, np.array([5.0, 4.0, 3.0, 2.0]) * 0.29 / (k + 0.29), rtol=1e-8)
    np.testing.assert_allclose(s.force_n, k * s.dx_mm, rtol=1e-8)  # no friction: spring force = rod force


def test_guide_friction_is_a_hysteresis_band_of_two_f() -> None:
    build = ProbeBuild(G.x_mm, G.y_mm, G.k_n_per_mm, (12.7,) * 4, (0.01,) * 4)
    w = CameraWorld(build)
    rods = SpringRods([0.3] * 4)
    k = np.asarray(G.k_n_per_mm)
    pressed = w.press([6.0] * 4, rods).dx_mm
    np.testing.assert_allclose(pressed, (0.3 * 6.0 - 0.01) / (k + 0.3), rtol=1e-7)  # springs short of the rods
    w.press([8.0] * 4, rods)
    released = w.press([6.0] * 4, rods).dx_mm
    np.testing.assert_allclose(released - pressed, 0.02 / (k + 0.3), rtol=1e-6)
    held = w.press([6.0 + 0.001] * 4, rods).dx_mm  # back inside the band: stuck
    np.testing.assert_array_equal(held, released)
    w.press([-1.0] * 4, rods)  # off the sample: each spring stops where f holds it
    np.testing.assert_allclose(w.dx, 0.01 / k, rtol=1e-6)


def test_stroke_end_stops_an_indenter() -> None:
    w = CameraWorld(ideal())
    s = w.press([20.0] * 4, SpringRods([5.0] * 4))
    assert s.dx_mm[0] == pytest.approx(10.0) and s.indentation_mm[0] == pytest.approx(10.0)


def test_drawn_probe_stays_within_its_tolerances() -> None:
    spec = ProbeErrorSpec()
    b = ProbeBuild.draw(G.x_mm, G.y_mm, G.k_n_per_mm, 12.7, spec, np.random.default_rng(3))
    rel = np.asarray(b.k_n_per_mm) / np.asarray(G.k_n_per_mm) - 1
    assert np.all(np.abs(rel) <= spec.spring_tolerance) and np.any(np.abs(rel) > 0.01)
    assert np.all(np.abs(np.asarray(b.px_per_mm) / 12.7 - 1) <= spec.scale_tolerance)
    assert spec.distortion_k1[0] <= b.distortion_k1 <= spec.distortion_k1[1]
    assert b == ProbeBuild.draw(G.x_mm, G.y_mm, G.k_n_per_mm, 12.7, spec, np.random.default_rng(3))  # seeded


def test_layer_kernel_limits() -> None:
    assert layer_kernel(40.0, 0.3) == 1.0 and layer_kernel(8.0, 0.45) == pytest.approx(1.0, abs=1e-4)
    # thin compressible layer: w = p h (1 + nu)(1 - 2 nu) / ((1 - nu) E) (confined compression), i.e.
    # K(t) / t -> (1 - 2 nu) / (2 (1 - nu)^2) as t -> 0
    for nu in (0.2, 0.3, 0.4):
        assert layer_kernel(1e-4, nu) / 1e-4 == pytest.approx((1 - 2 * nu) / (2 * (1 - nu) ** 2), rel=1e-3)


def test_layer_deflection_tends_to_boussinesq_and_heaves_on_a_thin_incompressible_layer() -> None:
    assert layer_deflection_factor(8.0, 1e4, 0.5) == pytest.approx(1.0, abs=0.002)
    assert layer_deflection_factor(8.0, 20.0, 0.5) == pytest.approx(0.349, abs=0.01)
    assert -0.2 < layer_deflection_factor(8.0, 5.0, 0.5) < 0.0  # incompressible: the surface rises around


class LinearTissue:
    def force_n(self, x_mm: object, y_mm: object, depth_mm: object, *, indenter_radius_mm: float = 2.0) -> object:
        return 0.1 * np.asarray(depth_mm)


def test_neighbours_lower_the_surface_under_a_tip() -> None:
    tissue = TissueTips(LinearTissue(), G.x_mm, G.y_mm, 2.0, 26.4, 0.5, 1e4)
    g = 1.0 / (math.pi * 26.4e-3 / 0.75 * 8.0)  # Boussinesq: (1 - nu^2) / (pi E rho)
    assert tissue.coupling[1, 0] == pytest.approx(g, rel=0.01)
    coupled = CameraWorld(ideal()).press([4.0] * 4, tissue)
    tissue.coupling[:] = 0.0
    alone = CameraWorld(ideal()).press([4.0] * 4, tissue)
    assert np.all(coupled.force_n < alone.force_n)
    sink = TissueTips(LinearTissue(), G.x_mm, G.y_mm, 2.0, 26.4, 0.5, 1e4).coupling @ coupled.force_n
    np.testing.assert_allclose(coupled.indentation_mm, 4.0 - coupled.dx_mm - sink, atol=1e-7)
