"""Pressure regulator plant: first-order lag, slew limit, bounds, exact integration."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from models.regulator import RegulatorPlant

setpoints = st.floats(-50.0, 300.0)
dts = st.floats(0.0, 0.5)


def test_defaults_and_interface() -> None:
    plant = RegulatorPlant()
    assert plant.pressure_kpa == 0.0
    assert plant.tau_s == 0.05 and plant.rate_limit_kpa_s == 50.0 and plant.max_kpa is None
    p = plant.step(1.0, 0.01)
    assert p == plant.pressure_kpa and 0.0 < p < 1.0


def test_small_steps_follow_the_first_order_lag_exactly() -> None:
    plant = RegulatorPlant(tau_s=0.1, rate_limit_kpa_s=1e6)
    for k in range(1, 51):
        plant.step(2.0, 0.01)
        assert plant.pressure_kpa == pytest.approx(2.0 * (1 - math.exp(-0.01 * k / 0.1)), rel=1e-12)


def test_large_steps_are_slew_limited_then_settle() -> None:
    plant = RegulatorPlant(tau_s=0.05, rate_limit_kpa_s=50.0)
    assert plant.step(100.0, 0.5) == pytest.approx(25.0, abs=1e-12)  # 50 kPa/s for 0.5 s
    assert plant.step(100.0, 1.0) == pytest.approx(75.0, abs=1e-12)
    # The ramp ends 2.5 kPa (= rate * tau) short of the target, then decays exponentially.
    plant.step(100.0, 0.45)
    assert plant.pressure_kpa == pytest.approx(100.0 - 2.5, abs=1e-12)
    plant.step(100.0, 0.05)
    assert plant.pressure_kpa == pytest.approx(100.0 - 2.5 * math.exp(-1.0), abs=1e-12)
    plant.step(100.0, 2.0)
    assert plant.pressure_kpa == pytest.approx(100.0, abs=1e-12)


@given(sp=setpoints, start=st.floats(0.0, 200.0), dt=dts, n=st.integers(2, 50))
def test_result_does_not_depend_on_step_size(sp: float, start: float, dt: float, n: int) -> None:
    one, many = RegulatorPlant(pressure_kpa=start), RegulatorPlant(pressure_kpa=start)
    one.step(sp, dt)
    for _ in range(n):
        many.step(sp, dt / n)
    assert many.pressure_kpa == pytest.approx(one.pressure_kpa, abs=1e-9)


@given(
    steps=st.lists(st.tuples(setpoints, dts), min_size=1, max_size=30),
    cap=st.one_of(st.none(), st.floats(0.0, 150.0)),
    tau=st.floats(0.0, 1.0),
    rate=st.floats(0.1, 1000.0),
)
def test_bounded_slew_limited_and_never_overshoots(
    steps: list[tuple[float, float]], cap: float | None, tau: float, rate: float
) -> None:
    plant = RegulatorPlant(tau_s=tau, rate_limit_kpa_s=rate, max_kpa=cap)
    for sp, dt in steps:
        before = plant.pressure_kpa
        after = plant.step(sp, dt)
        target = min(max(sp, 0.0), math.inf if cap is None else cap)
        assert after >= 0.0
        assert cap is None or after <= cap
        assert abs(after - before) <= rate * dt * (1 + 1e-12) + 1e-12
        # moves towards the clipped set-point and never past it
        assert min(before, target) - 1e-9 <= after <= max(before, target) + 1e-9


def test_negative_setpoint_vents_to_zero_and_cap_is_hard() -> None:
    plant = RegulatorPlant(pressure_kpa=10.0)
    plant.step(-20.0, 5.0)
    assert plant.pressure_kpa == pytest.approx(0.0, abs=1e-12)
    capped = RegulatorPlant(max_kpa=40.0)
    capped.step(500.0, 10.0)
    assert capped.pressure_kpa == pytest.approx(40.0, abs=1e-12)


def test_zero_tau_and_infinite_rate_are_instant() -> None:
    assert RegulatorPlant(tau_s=0.0, rate_limit_kpa_s=math.inf).step(7.0, 1e-6) == 7.0
    assert RegulatorPlant(tau_s=0.0, rate_limit_kpa_s=10.0).step(7.0, 1.0) == 7.0
    assert RegulatorPlant(tau_s=0.0, rate_limit_kpa_s=10.0).step(7.0, 0.5) == pytest.approx(5.0)


def test_zero_dt_changes_nothing_and_reset_sets_state() -> None:
    plant = RegulatorPlant(pressure_kpa=3.0)
    assert plant.step(50.0, 0.0) == 3.0
    plant.reset(12.5)
    assert plant.pressure_kpa == 12.5


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: RegulatorPlant(tau_s=-1.0), "tau_s must be finite and >= 0"),
        (lambda: RegulatorPlant(rate_limit_kpa_s=0.0), "rate_limit_kpa_s must be > 0"),
        (lambda: RegulatorPlant(max_kpa=-1.0), "max_kpa must be finite"),
        (
            lambda: RegulatorPlant(max_kpa=10.0, pressure_kpa=20.0),
            r"pressure_kpa must be in \[0, 10.0\]",
        ),
        (lambda: RegulatorPlant().step(float("nan"), 0.1), "setpoint_kpa must be finite"),
        (lambda: RegulatorPlant().step(1.0, -0.1), "dt_s must be finite and >= 0"),
    ],
)
def test_bad_arguments_raise(make: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make()  # type: ignore[operator]
