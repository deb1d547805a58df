"""Algorithm 1's 1-D Kalman filter bank (models/kalman.py): gains, predict-only steps, the paper's tuning."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.kalman import KalmanParams, ScalarKalmanBank, steady_state_gain, steady_state_variance


def test_steady_state_gain_of_the_papers_tuning() -> None:
    assert steady_state_gain() == pytest.approx(0.1392, abs=5e-4)
    prior, post = steady_state_variance(0.09, 4.0)
    # the Riccati fixed point: predict adds q to the posterior, update shrinks the prior by (1 - k)
    assert prior == pytest.approx(post + 0.09)
    assert post == pytest.approx(prior * 4.0 / (prior + 4.0))


def test_filter_gain_converges_to_the_steady_state_gain() -> None:
    bank = ScalarKalmanBank(4)
    for _ in range(200):
        bank.step(np.zeros(4))
    np.testing.assert_allclose(bank.gain, steady_state_gain(), rtol=1e-9)
    np.testing.assert_allclose(bank.p, steady_state_variance(0.09, 4.0)[1], rtol=1e-9)


@pytest.mark.parametrize(("q", "r", "k"), [(0.0, 4.0, 0.0), (0.09, 0.0, 1.0), (1.0, 1.0, (1 + math.sqrt(5)) / 2 / ((1 + math.sqrt(5)) / 2 + 1))])
def test_steady_state_gain_limits(q: float, r: float, k: float) -> None:
    assert steady_state_gain(q, r) == pytest.approx(k)


def test_first_measurement_initialises_then_algorithm_1_updates() -> None:
    bank = ScalarKalmanBank(2)
    assert not bank.initialized.any()
    bank.step(np.array([10.0, 20.0]))
    np.testing.assert_array_equal(bank.x, [10.0, 20.0])
    np.testing.assert_array_equal(bank.p, [6.0, 6.0])
    bank.step(np.array([11.0, 20.0]))
    k = (6.0 + 0.09) / (6.0 + 0.09 + 4.0)  # Algorithm 1 lines 14 and 16
    np.testing.assert_allclose(bank.gain, [k, k])
    np.testing.assert_allclose(bank.x, [10.0 + k * 1.0, 20.0])
    np.testing.assert_allclose(bank.p, (1 - k) * 6.09)


def test_lost_markers_only_predict() -> None:
    bank = ScalarKalmanBank(4)
    bank.step(np.array([1.0, 2.0, 3.0, 4.0]))
    for _ in range(5):
        bank.step(np.array([1.5, 2.5, 3.5, 4.5]))
    x, p = bank.x.copy(), bank.p.copy()
    lost = np.array([False, True, False, True])
    for i in range(3):
        bank.step(np.array([1.5, 99.0, 3.5, math.nan]), valid=~lost)  # NaN is predict-only too
        np.testing.assert_array_equal(bank.x[lost], x[lost])
        np.testing.assert_allclose(bank.p[lost], p[lost] + 0.09 * (i + 1))
        assert bank.gain[lost].tolist() == [0.0, 0.0]
    assert (bank.x[~lost] > x[~lost]).all()
    # recovery: the grown variance gives a larger gain than the markers that kept tracking
    bank.step(np.array([1.5, 2.5, 3.5, 4.5]))
    assert bank.gain[1] > bank.gain[0]


def test_reset_and_uninitialised_filters() -> None:
    bank = ScalarKalmanBank(3, KalmanParams(q=0.1, r=1.0, p0=2.0))
    bank.step(np.array([1.0, 1.0, 1.0]))
    bank.reset(np.array([5.0, 0.0, 7.0]), mask=np.array([True, False, True]))
    np.testing.assert_array_equal(bank.x, [5.0, 1.0, 7.0])
    assert bank.p[0] == 2.0 and bank.p[2] == 2.0
    bank.reset(mask=np.array([False, True, False]))
    assert bank.initialized.tolist() == [True, False, True]
    bank.predict()
    assert bank.p[1] == 2.0  # an uninitialised filter does not predict


def test_state_views_are_read_only() -> None:
    bank = ScalarKalmanBank(4)
    with pytest.raises(ValueError):
        bank.x[0] = 1.0
    out = bank.step(np.ones(4))
    with pytest.raises(ValueError):
        out[:] = 0.0


def test_filtered_noise_matches_theory() -> None:
    """A still marker with 0.3 px white noise: sd of the estimate = 0.3 sqrt(k / (2 - k)) in steady state."""
    rng = np.random.default_rng(7)
    bank = ScalarKalmanBank(4)
    out = []
    for _ in range(6000):
        out.append(bank.step(100.0 + rng.normal(0.0, 0.3, 4)).copy())
    sd = np.asarray(out[100:]).std(axis=0)
    k = steady_state_gain()
    np.testing.assert_allclose(sd, 0.3 * math.sqrt(k / (2 - k)), rtol=0.1)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(-500, 500), st.booleans()), min_size=1, max_size=40),
       st.floats(0.001, 5.0), st.floats(0.01, 20.0), st.floats(0.0, 20.0))
def test_bank_equals_a_scalar_reference(seq: list[tuple[float, bool]], q: float, r: float, p0: float) -> None:
    """Vectorised bank (marker 0 = the sequence, marker 1 = its mirror) vs Algorithm 1 written out in scalars."""
    bank = ScalarKalmanBank(2, KalmanParams(q, r, p0))
    x = p = None
    for z, ok in seq:
        bank.step(np.array([z, -z]), valid=np.array([ok, ok]))
        if x is None or p is None:
            if ok:
                x, p = z, p0
            continue
        p += q
        if ok:
            k = p / (p + r)
            x += k * (z - x)
            p *= 1 - k
    if x is None:
        assert not bank.initialized.any()
    else:
        assert bank.x[0] == pytest.approx(x, abs=1e-9) and bank.x[1] == pytest.approx(-x, abs=1e-9)
        assert bank.p[0] == pytest.approx(p, rel=1e-9)


@pytest.mark.parametrize("kwargs", [{"q": -1.0}, {"r": math.nan}, {"p0": math.inf}, {"q": 0.0, "r": 0.0}])
def test_bad_parameters_are_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="KalmanParams"):
        KalmanParams(**kwargs)


def test_shape_errors_name_the_argument() -> None:
    bank = ScalarKalmanBank(4)
    with pytest.raises(ValueError, match="z must have shape"):
        bank.update(np.zeros(3))
    with pytest.raises(ValueError, match="mask must have shape"):
        bank.step(np.zeros(4), valid=np.ones(2, dtype=bool))
    with pytest.raises(ValueError, match="n must be"):
        ScalarKalmanBank(0)
