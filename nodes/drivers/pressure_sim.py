"""Simulated pressure regulator: the first-order, rate-limited plant of ``models.regulator`` behind the
:class:`nodes.drivers.pressure.PressureDriver` interface, on the node's (possibly simulated) clock.

A real regulator does not hold its set-point exactly: the outlet wanders about the plant's response as an
Ornstein-Uhlenbeck process (``tracking_kpa`` sigma, ``tracking_tau_s`` correlation time; 0.25 kPa keeps it within
about +-0.5 kPa, the issue's regulator tracking error), seeded. The read-back is the outlet plus white noise.

Both depend only on simulated time and the seed, not on how often or when the driver is called (a composed run
and a multi-process one poll at different instants): the wander is stepped on a fixed 10 ms grid of absolute
simulated time, one draw per grid step, and each read-back's noise is drawn from the seed and its time stamp
(counted from the whole second of the driver's opening: simulated time starts on a whole second, composed or not)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from models.regulator import RegulatorPlant
from nodes.drivers.pressure import (
    FLAG_CLAMPED,
    PressureCounters,
    PressureNotConnectedError,
    PressureReading,
    PressureStatus,
)

__all__ = ["SimPressureDriver"]

_WANDER_STEP_NS = 10_000_000
_MAX_WANDER_STEPS = 100_000
"""Wander steps drawn one by one at most (1000 s); a longer gap is stepped at once (its exact distribution)."""


class SimPressureDriver:
    """A regulator that follows its set-point with lag ``tau_s`` and slew limit, never above ``max_kpa``.

    ``stuck_at_kpa`` (fault injection) freezes the output as a jammed valve would; ``lost`` makes every call raise
    as an unplugged device does.
    """

    def __init__(
        self,
        clock: Callable[[], int],
        max_kpa: float,
        *,
        tau_s: float = 0.05,
        rate_limit_kpa_s: float = 50.0,
        noise_kpa: float = 0.0,
        tracking_kpa: float = 0.0,
        tracking_tau_s: float = 0.3,
        seed: int = 0,
    ) -> None:
        self._clock = clock
        self._max = float(max_kpa)
        self._plant = RegulatorPlant(tau_s=tau_s, rate_limit_kpa_s=rate_limit_kpa_s, max_kpa=max_kpa)
        self._noise = noise_kpa
        self._seed = seed
        self._rng = np.random.default_rng(seed)
        self._track_sigma = float(tracking_kpa)
        self._track_tau = float(tracking_tau_s)
        self._wobble = self._track_sigma * float(self._rng.standard_normal()) if tracking_kpa > 0 else 0.0
        self._wobble_t: int | None = None  # the grid instant the wander's value belongs to
        self._opened = 0
        self._setpoint = 0.0
        self._t: int | None = None
        self._polls = 0
        self._clamped = 0
        self.stuck_at_kpa: float | None = None
        self.lost = False

    def _advance(self) -> None:
        now = self._clock()
        if self._t is not None and now > self._t:
            dt = (now - self._t) / 1e9
            self._plant.step(self._setpoint, dt)
        if self._track_sigma > 0:
            self._wander_to(now)
        self._t = now

    def _wander_to(self, now: int) -> None:
        """Step the wander (exact OU steps of the grid's 10 ms) to the last grid instant not after ``now``."""
        grid = now - now % _WANDER_STEP_NS
        if self._wobble_t is None:
            self._wobble_t = grid
            return
        n = (grid - self._wobble_t) // _WANDER_STEP_NS
        if n <= 0:
            return
        k = math.exp(-_WANDER_STEP_NS / 1e9 / self._track_tau)
        w = self._wobble
        if n > _MAX_WANDER_STEPS:  # a long gap (a clock that jumped): the n steps in one, exactly, in O(1)
            kn = k ** min(n, 1 << 20)
            w = kn * w + self._track_sigma * math.sqrt(1 - kn * kn) * float(self._rng.standard_normal())
        else:
            kick = self._track_sigma * math.sqrt(1 - k * k)
            for z in self._rng.standard_normal(int(n)).tolist():
                w = k * w + kick * z
        self._wobble, self._wobble_t = w, grid

    def _reading(self, flags: frozenset[str] = frozenset()) -> PressureReading:
        if self.lost:
            raise PressureNotConnectedError("sim: device lost (fault injection)")
        self._advance()
        self._polls += 1
        p = min(max(0.0, self._plant.pressure_kpa + self._wobble * (self._plant.pressure_kpa > 0)), self._max)
        if self.stuck_at_kpa is not None:
            p = self.stuck_at_kpa
        if self._noise:
            noise = np.random.default_rng([self._seed, 2, max(0, (self._t or 0) - self._opened)]).standard_normal()
            p = max(0.0, p + self._noise * float(noise))
        return PressureReading(self._t or 0, self._setpoint, p, flags)

    def open(self) -> None:
        self._t = self._clock()
        self._opened = self._t // 1_000_000_000 * 1_000_000_000  # its whole second: a run starts on one

    def close(self) -> None:
        """Nothing to release."""

    def set_setpoint(self, kpa: float) -> PressureReading:
        if not math.isfinite(kpa):
            raise ValueError(f"set-point must be a finite number of kPa, got {kpa!r}")
        self._advance()
        target = min(max(kpa, 0.0), self._max)
        flags = frozenset({FLAG_CLAMPED}) if target != kpa else frozenset()
        self._clamped += kpa > self._max
        self._setpoint = target
        return self._reading(flags)

    def hold(self) -> PressureReading:
        return self._reading(frozenset({"HLD"}))

    def vent(self) -> PressureReading:
        return self.set_setpoint(0.0)

    def read(self, timeout_s: float = 0.0) -> PressureReading | None:
        return self._reading()

    def status(self) -> PressureStatus:
        return PressureStatus(
            connected=not self.lost,
            last_error="sim: device lost" if self.lost else None,
            counters=PressureCounters(polls=self._polls, clamped=self._clamped),
            max_kpa=self._max,
            commanded_kpa=self._setpoint,
            last_reading=None,
            port="sim",
        )
