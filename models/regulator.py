"""Electronic pressure regulator plant: a first-order lag with a slew-rate limit and a hard cap.

Continuous model, pressure p and set-point s in kPa:

    dp/dt = clip((s - p) / tau, -R, +R),   s clipped to [0, max_kpa]

``step`` integrates it *exactly* over dt (a ramp at the rate limit R until |s - p| <= R tau, then
the exponential tail), so the result does not depend on how a caller slices time: ten steps of
dt/10 land where one step of dt does. Because p moves monotonically towards a clipped s, it can
never go negative or above max_kpa. Not modelled: supply-pressure droop, valve dead band,
hysteresis, sensor noise (the simulator adds noise from the phantom's ``noise.pressure_kpa``).
"""

from __future__ import annotations

import math


class RegulatorPlant:
    """State of one pressure regulator; call ``step`` once per simulation tick."""

    def __init__(
        self,
        tau_s: float = 0.05,
        rate_limit_kpa_s: float = 50.0,
        max_kpa: float | None = None,
        pressure_kpa: float = 0.0,
    ) -> None:
        """tau_s: lag time constant (s, >= 0; 0 = no lag). rate_limit_kpa_s: slew limit (kPa/s,
        > 0, may be inf). max_kpa: hard cap on set-point and pressure (kPa) or None. pressure_kpa:
        initial pressure (kPa), within [0, max_kpa]."""
        if not (math.isfinite(tau_s) and tau_s >= 0):
            raise ValueError(f"RegulatorPlant: tau_s must be finite and >= 0 s, got {tau_s!r}")
        if math.isnan(rate_limit_kpa_s) or rate_limit_kpa_s <= 0:
            raise ValueError(
                f"RegulatorPlant: rate_limit_kpa_s must be > 0 kPa/s, got {rate_limit_kpa_s!r}"
            )
        if max_kpa is not None and not (math.isfinite(max_kpa) and max_kpa >= 0):
            raise ValueError(
                f"RegulatorPlant: max_kpa must be finite and >= 0 kPa or None, got {max_kpa!r}"
            )
        self.tau_s = float(tau_s)
        self.rate_limit_kpa_s = float(rate_limit_kpa_s)
        self.max_kpa = None if max_kpa is None else float(max_kpa)
        self._pressure = 0.0
        self.reset(pressure_kpa)

    @property
    def pressure_kpa(self) -> float:
        """Current output pressure (kPa)."""
        return self._pressure

    def reset(self, pressure_kpa: float = 0.0) -> None:
        """Set the output pressure (kPa) directly, e.g. after a simulated vent."""
        upper = math.inf if self.max_kpa is None else self.max_kpa
        if not (math.isfinite(pressure_kpa) and 0.0 <= pressure_kpa <= upper):
            raise ValueError(
                f"RegulatorPlant: pressure_kpa must be in [0, {upper}] kPa, got {pressure_kpa!r}"
            )
        self._pressure = float(pressure_kpa)

    def step(self, setpoint_kpa: float, dt_s: float) -> float:
        """Advance dt_s seconds (>= 0) towards setpoint_kpa (clipped to [0, max_kpa]); return kPa."""
        if not math.isfinite(setpoint_kpa):
            raise ValueError(
                f"RegulatorPlant.step: setpoint_kpa must be finite, got {setpoint_kpa!r}"
            )
        if not (math.isfinite(dt_s) and dt_s >= 0):
            raise ValueError(f"RegulatorPlant.step: dt_s must be finite and >= 0 s, got {dt_s!r}")
        target = max(setpoint_kpa, 0.0)
        if self.max_kpa is not None:
            target = min(target, self.max_kpa)
        err = target - self._pressure
        if err == 0.0 or dt_s == 0.0:
            return self._pressure
        direction = math.copysign(1.0, err)
        rate = self.rate_limit_kpa_s
        if math.isinf(rate):
            band, ramp_time = math.inf, -math.inf
        else:
            band = rate * self.tau_s  # |err| below which the lag, not the slew limit, rules
            ramp_time = (abs(err) - band) / rate
        if ramp_time >= dt_s:
            self._pressure += direction * rate * dt_s
            return self._pressure
        remaining = dt_s - max(ramp_time, 0.0)
        err_left = min(abs(err), band)
        if self.tau_s > 0.0:
            err_left *= math.exp(-remaining / self.tau_s)
        else:
            err_left = 0.0
        self._pressure = target - direction * err_left
        return self._pressure
