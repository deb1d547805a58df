"""The force touch-off's estimate of where contact began: the contact-law fit (models.surface.contact_onset_z) on
made-up laws, and the touch-off on the simulated arm over the simulated world's dome (mock clock), stepped often
and stepped rarely, as a busy PC steps it. The same touch-off on the UR emulator: tests/test_touchoff_ur.py."""

from __future__ import annotations

import dataclasses
import math
import random
from collections.abc import Callable

import numpy as np
import pytest

from models.phantom import load_phantom
from models.surface import contact_onset_z, touch_points
from models.world import TissueWorld
from nodes.drivers.robot import TcpState
from nodes.drivers.robot_sim import SimRobotDriver
from nodes.scanner.touchoff import TouchOff, TouchOffConfig

DOME = "phantoms/specimens/dome_6_3.yaml"
POWERS = tuple(1.0 + 0.05 * k for k in range(31))


def rise(z0: float, k: float, p: float, depths: np.ndarray) -> list[tuple[float, float]]:
    return [(z0 - float(d), float((k * d) ** p)) for d in depths]


def test_the_onset_of_a_known_law_and_of_a_stiffening_one() -> None:
    depths = np.linspace(0.3, 1.5, 7)
    # a sphere on a thick layer (1.5): a fixed 1.5 and a free exponent both find the onset
    hertz = rise(5.0, 0.4, 1.5, depths)
    assert contact_onset_z(hertz, (1.5,)) == pytest.approx(5.0, abs=1e-9)
    assert contact_onset_z(hertz, POWERS) == pytest.approx(5.0, abs=1e-9)
    # a thin layer stiffening to 1.9: a fixed 1.5 puts the surface low, the free exponent does not
    thin = rise(5.0, 0.4, 1.9, depths)
    fixed = contact_onset_z(thin, (1.5,))
    assert fixed is not None and fixed < 5.0 - 0.1
    assert contact_onset_z(thin, POWERS) == pytest.approx(5.0, abs=1e-6)
    # no power law at all (a half-space term and a stiffening one): weighing the readings by their size, the small
    # ones near the onset count, and it lands within 0.15 mm (in absolute error, 0.2 mm off)
    both = [(5.0 - float(d), 0.1 * d ** 1.5 + 0.05 * d ** 3) for d in np.linspace(0.1, 2.0, 10)]
    assert contact_onset_z(both, POWERS) == pytest.approx(5.0, abs=0.15)
    # a spring (1) from three readings
    assert contact_onset_z(rise(2.0, 3.0, 1.0, depths[:3]), (1.0,)) == pytest.approx(2.0, abs=1e-9)


def test_the_onset_is_none_where_the_readings_cannot_tell() -> None:
    depths = np.linspace(0.3, 1.5, 7)
    assert contact_onset_z(rise(5.0, 0.4, 1.5, depths[:3]), POWERS) is None  # 3 readings, 3 unknowns
    assert contact_onset_z(rise(5.0, 0.4, 1.5, depths[:2]), (1.5,)) is None
    assert contact_onset_z([(5.0, 0.1), (5.0, 0.2), (5.0, 0.3), (5.0, 0.4)], POWERS) is None  # no spread in z
    # a signal that falls as the probe goes down is not a contact
    assert contact_onset_z([(5.0 - d, 1.0 / (1.0 + d)) for d in depths], POWERS) is None


class ForceArm(SimRobotDriver):
    """The simulated arm with a TCP force from the simulated world (the tissue's FE-grounded response, models.world)
    read by a sensor with an offset and white noise: the UR emulator's force, without the emulator."""

    def __init__(self, world: TissueWorld, surface_z: Callable[[float, float], float],
                 home_mm: tuple[float, float, float], clock: Callable[[], int], bias_n: float,
                 noise_n: float, seed: int = 0, stale: int = 0) -> None:
        super().__init__(home_mm, clock=clock)
        self.world, self.surface_z, self.bias_n, self.noise_n = world, surface_z, bias_n, noise_n
        self.rng = random.Random(seed)
        self.stale, self._reads = stale, 0
        self._held: TcpState | None = None

    def state(self) -> TcpState:
        """With ``stale``, each reading is answered again ``stale`` more times (a stream behind its reader)."""
        self._reads += 1
        if self._held is not None and self._reads % (self.stale + 1):
            return self._held
        self._held = self._read()
        return self._held

    def _read(self) -> TcpState:
        st = super().state()
        x, y, z = st.pose[:3]
        depth = float(self.surface_z(x, y)) - z
        fz = float(self.world.force_n(x, y, depth, indenter_radius_mm=3.5)) if depth > 0 else 0.0
        fz += self.bias_n + self.rng.gauss(0.0, self.noise_n)
        return dataclasses.replace(st, force_n=(0.0, 0.0, fz, 0.0, 0.0, 0.0))


def touch_off(step_s: float, bias_n: float = 2.0, noise_n: float = 0.0, seed: int = 0,
              stale: int = 0) -> tuple[TouchOff, list[float]]:
    """Nine force touches over the dome's crest, the touch-off stepped every ``step_s`` of simulated time, the force
    read off by ``bias_n`` with a noise of sigma ``noise_n``."""
    truth = load_phantom(DOME)
    now = [0]
    arm = ForceArm(TissueWorld(truth), lambda x, y: float(truth.surface_z(x, y)), (20.0, 10.0, 7.0),
                   lambda: now[0], bias_n, noise_n, seed, stale)
    arm.connect()
    touch = TouchOff(arm, touch_points((20.0, 10.0, 40.0, 30.0), 3), TouchOffConfig(
        signal="force", start_z_mm=7.0, floor_z_mm=0.5, search_speed_mm_s=5.0, transit_speed_mm_s=60.0,
        accel_mm_s2=1000.0, threshold=0.3))
    touch.start()
    for _ in range(int(600 / step_s)):
        if touch.done or touch.failed:
            break
        now[0] += int(step_s * 1e9)
        touch.step()
    return touch, [z - float(truth.surface_z(x, y)) for x, y, z in touch.touches]


@pytest.mark.parametrize("step_s", [0.002, 0.08, 0.2])
def test_the_force_touch_finds_the_dome_however_rarely_it_is_stepped(step_s: float) -> None:
    """A perfect sensor offset by 2 N. Stepped every 2 ms the rise (0.015-0.3 N, ~1.3 mm at 5 mm/s) is read ~130
    times; every 80 ms ~3-4 times, every 200 ms once or twice, and the descents are repeated more slowly until it is
    read 16 times. The surface is found within -0.07..+0.05 mm each time (the layer's stiffening is not all a power
    law, and Hertz's exponent is the prior)."""
    touch, errors = touch_off(step_s)
    assert touch.done, touch.error
    assert touch.force_zero_n == pytest.approx(2.0)  # the sensor's offset, read at rest over the point
    assert len(errors) == 9 and all(-0.07 < e < 0.05 for e in errors), errors
    if step_s == 0.002:
        assert touch.reapproaches == 0
    if step_s == 0.2:
        assert touch.reapproaches >= 9  # every point at least once


@pytest.mark.system
def test_a_wrist_sensor_s_noise_is_read_at_rest_and_the_rise_fitted_above_it() -> None:
    """A wrist F/T sensor (sigma 3 mN, as the UR test's), four noise draws, stepped every 2, 20 and 50 ms: its spread
    is read at rest and the rise fitted from 0.015 N up; 108 touches within 0.12 mm, rms 0.034 mm. The exponent's
    prior (sigma 0.15) and the 16 readings are what hold it: a prior of 0.25 puts one 0.14 mm off, 8 readings or
    both changes an rms of 0.044 mm."""
    errors = []
    for seed in range(4):
        for step_s in (0.002, 0.02, 0.05):
            touch, e = touch_off(step_s, noise_n=0.003, seed=seed)
            assert touch.done, touch.error
            assert 0.002 < touch.force_noise_n < 0.004 and len(e) == 9
            errors += e
    assert max(abs(e) for e in errors) < 0.12, max(abs(e) for e in errors)
    assert math.sqrt(sum(e * e for e in errors) / len(errors)) < 0.038


def test_readings_of_a_stream_behind_its_reader_are_not_taken_twice_nor_from_before_a_stop() -> None:
    """The driver's stream three packages behind the steps (each state answered four times, as ur_rtde's is when its
    receive thread lags): a reading read again is not a new one, and after a stop the stopped arm's readings, deep
    in the tissue, do not count for the next descent. The same 108 touches as above, within 0.12 mm, rms 0.034."""
    errors = []
    for seed in range(4):
        for step_s in (0.002, 0.02, 0.05):
            touch, e = touch_off(step_s / 4, noise_n=0.003, seed=seed, stale=3)
            assert touch.done, touch.error
            errors += e
    assert max(abs(e) for e in errors) < 0.12, max(abs(e) for e in errors)
    assert math.sqrt(sum(e * e for e in errors) / len(errors)) < 0.038


def test_a_rise_read_too_rarely_even_at_an_eighth_of_the_speed_fails_the_touch_off_naming_the_point() -> None:
    """Stepped once a second the rise is read once or twice even after three slower descents: the touch-off fails,
    naming the point, instead of taking the depth where the threshold was crossed (1.5 mm into this dome) for the
    surface."""
    touch, errors = touch_off(1.0)
    assert touch.failed and not errors and touch.reapproaches == 3
    assert touch.error.startswith("touch-off by force at (20, 10) mm") and "too few to find where it began" in (
        touch.error), touch.error


def test_a_robot_s_coarse_force_sensor_cannot_touch_off_soft_tissue_and_says_so() -> None:
    """A UR's built-in sensor (sigma ~1 N) against a 0.3 N threshold: noise alone would cross it, and this dome
    pushes back 0.3 N only 1.5 mm in. The touch-off fails before descending, naming the spread and the way out."""
    touch, errors = touch_off(0.002, noise_n=1.0)
    assert touch.failed and not errors
    assert "spread of" in touch.error and "would be crossed by noise" in touch.error, touch.error
    assert "touchoff: heights or indenters" in touch.error
