"""Contact laws of the air-float paper (eqs. 5-8): units, inverses, the Fig. 11b relation, fitting."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.contact import (
    FitResult,
    corrected_depth,
    corrected_force,
    corrected_modulus,
    fit_force_depth,
    fung_force,
    fung_modulus,
    hertz_depth,
    hertz_force,
    hertz_modulus,
    thickness_correction,
)

R = 4.0  # mm, the paper's indenter (d/r = 5 for 20 mm samples)
T = 20.0  # mm

moduli = st.floats(1.0, 500.0)  # kPa
depths = st.floats(0.01, 5.0)  # mm
radii = st.floats(1.0, 8.0)
thicknesses = st.floats(2.0, 50.0)
nus = st.floats(0.0, 0.5)


def test_hertz_force_by_hand_in_newtons_and_kpa() -> None:
    # eq. 6 solved for F with E = 26.4 kPa = 0.0264 N/mm^2, r = 4 mm, d = 3 mm, nu = 0.5
    expected = 8 * 0.0264 * 3.0 * np.sqrt(4.0 * 3.0) / (6 * (1 - 0.25))
    assert hertz_force(26.4, 3.0, R) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(0.4877, abs=1e-4)
    assert hertz_modulus(expected, 3.0, R) == pytest.approx(26.4, rel=1e-12)


@given(e=moduli, d=depths, r=radii, nu=nus)
def test_hertz_inverse_forward_and_depth_round_trip(
    e: float, d: float, r: float, nu: float
) -> None:
    f = hertz_force(e, d, r, nu)
    assert hertz_modulus(f, d, r, nu) == pytest.approx(e, rel=1e-10)
    assert hertz_depth(f, e, r, nu) == pytest.approx(d, rel=1e-9)


@given(e=moduli, d=depths, r=radii, t=thicknesses, nu=nus)
def test_corrected_is_hertz_times_dimitriadis(
    e: float, d: float, r: float, t: float, nu: float
) -> None:
    chi = np.sqrt(r * d) / t
    poly = 1 + 1.133 * chi + 1.283 * chi**2 + 0.769 * chi**3 + 0.0975 * chi**4
    assert thickness_correction(d, r, t) == pytest.approx(poly, rel=1e-12)
    f = corrected_force(e, d, r, t, nu)
    assert f == pytest.approx(hertz_force(e, d, r, nu) * poly, rel=1e-12)
    assert corrected_modulus(f, d, r, t, nu) == pytest.approx(e, rel=1e-10)
    assert hertz_modulus(f, d, r, nu) / corrected_modulus(f, d, r, t, nu) == pytest.approx(poly)


@given(e=moduli, d=depths, r=radii, t=thicknesses)
def test_corrected_depth_inverts_corrected_force(e: float, d: float, r: float, t: float) -> None:
    f = corrected_force(e, d, r, t)
    assert corrected_depth(f, e, r, t) == pytest.approx(d, rel=1e-9, abs=1e-12)


def test_fig11b_hertz_over_corrected_ratio_at_d_over_r_5() -> None:
    # Paper Fig. 11b, eq. 6 / eq. 7 estimates on 20 mm samples, r = 4 mm, ramps to ~3 mm.
    paper = [(35.0, 28.7), (29.7, 24.0), (9.88, 7.97), (17.4, 14.0)]
    ratios = [h / c for h, c in paper]
    assert min(ratios) > 1.21 and max(ratios) < 1.25
    # The model gives 1.22-1.24 over the end of the ramp ...
    for d in (2.7, 2.85, 3.0):
        assert 1.22 <= thickness_correction(d, R, T) <= 1.24
    # ... and every paper ratio corresponds to a depth near the 3 mm maximum indentation.
    grid = np.linspace(0.5, 4.0, 3501)
    corr = np.asarray(thickness_correction(grid, R, T))
    for ratio in ratios:
        d_at = grid[np.argmin(np.abs(corr - ratio))]
        assert 2.5 < d_at < 3.2, (ratio, d_at)
    # eq. 6 over-estimates, never under-estimates, with a thin sample.
    assert np.all(corr >= 1.0)


def test_fung_reduces_to_hertz_at_small_depth_and_round_trips() -> None:
    for d in (1e-6, 1e-4, 1e-2):
        ratio = fung_force(26.4, d, R, 0.0) / hertz_force(26.4, d, R)
        # eq. 8's polynomial is (3/5) t^3 / r * (1 + t / (5r) + O(t^2)): Hertz to first order.
        assert ratio - 1.0 == pytest.approx(np.sqrt(R * d) / (5 * R), rel=0.05)
    f = fung_force(26.4, 2.0, R, 3.0)
    assert fung_modulus(f, 2.0, R, 3.0) == pytest.approx(26.4, rel=1e-12)
    # A positive b stiffens the response with depth.
    assert fung_force(26.4, 3.0, R, 5.0) > fung_force(26.4, 3.0, R, 0.0)


def test_no_contact_gives_nan_modulus_and_zero_force() -> None:
    d = np.array([-1.0, 0.0, 1.0])
    e = np.asarray(hertz_modulus(np.array([0.1, 0.1, 0.1]), d, R))
    assert np.isnan(e[:2]).all() and np.isfinite(e[2])
    assert np.isnan(np.asarray(corrected_modulus(0.1, d, R, T))[:2]).all()
    assert np.isnan(np.asarray(fung_modulus(0.1, d, R, 1.0))[:2]).all()
    for f in (hertz_force(26.4, d, R), corrected_force(26.4, d, R, T), fung_force(26.4, d, R, 1.0)):
        assert np.all(np.asarray(f)[:2] == 0.0) and np.asarray(f)[2] > 0
    assert hertz_depth(-1.0, 26.4, R) == 0.0
    assert corrected_depth(0.0, 26.4, R, T) == 0.0


def test_scalar_in_float_out_and_vectorised_over_10k_samples() -> None:
    assert isinstance(hertz_modulus(0.5, 2.0, R), float)
    assert isinstance(corrected_modulus(0.5, 2.0, R, T), float)
    rng = np.random.default_rng(0)
    d = rng.uniform(0.1, 3.0, 10_000)
    e_true = rng.uniform(5.0, 150.0, 10_000)
    f = corrected_force(e_true, d, R, T)
    e = corrected_modulus(f, d, R, T)
    assert isinstance(e, np.ndarray) and e.shape == (10_000,)
    np.testing.assert_allclose(e, e_true, rtol=1e-10)
    assert np.asarray(hertz_modulus(f[:3], d[:3], R))[1] == pytest.approx(
        hertz_modulus(f[1], d[1], R)
    )


def test_fit_recovers_corrected_modulus_and_fig11_ratio_for_a_ramp() -> None:
    d = np.linspace(0.0, 3.0, 300)
    f = corrected_force(26.4, d, R, T)
    fit = fit_force_depth(f, d, R, T)
    assert isinstance(fit, FitResult)
    assert fit.E_corrected == pytest.approx(26.4, rel=1e-9)
    assert fit.residuals.corrected < 1e-12 < fit.residuals.hertz
    # A whole-ramp fit puts the Hertz over-estimate at ~1.2, as in Fig. 11b.
    assert 1.18 < fit.E_hertz / fit.E_corrected < 1.25
    # Fung with a free b fits this curve almost as well and lands close (paper: within ~3 %).
    assert fit.E_fung == pytest.approx(26.4, rel=0.03)


def test_fit_recovers_fung_parameters_and_tolerates_noise() -> None:
    d = np.linspace(0.05, 3.0, 200)
    f = np.asarray(fung_force(10.8, d, R, 4.0))
    fit = fit_force_depth(f, d, R, T)
    assert fit.E_fung == pytest.approx(10.8, rel=1e-6)
    assert fit.b_fung == pytest.approx(4.0, abs=1e-4)
    rng = np.random.default_rng(1)
    noisy = np.asarray(corrected_force(26.4, d, R, T)) + rng.normal(0, 0.005, d.size)
    assert fit_force_depth(noisy, d, R, T).E_corrected == pytest.approx(26.4, rel=0.02)


def test_fit_drops_points_before_contact() -> None:
    d = np.concatenate([np.linspace(-1.0, 0.0, 50), np.linspace(0.1, 3.0, 50)])
    f = np.where(d > 0, np.asarray(corrected_force(26.4, d, R, T)), 0.02)
    assert fit_force_depth(f, d, R, T).E_corrected == pytest.approx(26.4, rel=1e-9)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: hertz_modulus(1.0, 1.0, 0.0), "r must be finite and > 0"),
        (lambda: hertz_force(1.0, 1.0, R, nu=0.6), "poisson ratio"),
        (lambda: corrected_modulus(1.0, 1.0, R, -1.0), "thickness must be finite and > 0"),
        (lambda: hertz_depth(1.0, 0.0, R), r"E must be finite and > 0 \(kPa\)"),
        (lambda: fit_force_depth([1.0], [1.0], R, T), "need >= 2 finite points"),
        (lambda: fit_force_depth([1.0, 2.0], [1.0], R, T), "differ in length"),
    ],
)
def test_bad_arguments_raise_clear_errors(call: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()  # type: ignore[operator]


@settings(max_examples=50, deadline=None)
@given(e=moduli, t=thicknesses)
def test_fit_recovers_any_modulus_on_clean_data(e: float, t: float) -> None:
    d = np.linspace(0.1, 3.0, 40)
    fit = fit_force_depth(corrected_force(e, d, R, t), d, R, t)
    assert fit.E_corrected == pytest.approx(e, rel=1e-9)
    assert fit.E_hertz >= fit.E_corrected
