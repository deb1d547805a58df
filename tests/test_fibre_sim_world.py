"""The simulated air-float probe (nodes/drivers/fibre_sim.py, models/airfloat_device.py): the indentation comes from
the world, the force from the device's own law, the heights from the true surface; errors are drawn and recorded.

The world here is a test double (a Hertz half-space): these tests are about the device and geometry, not the
tissue mechanics, which models/world owns and tests against FE."""

from __future__ import annotations

import json

import numpy as np
import pytest

import models.contact
from models._arrays import ArrayLike
from models.airfloat import ForceCalibration, indentation_from_heights
from models.airfloat_device import ProbeErrors, TrueProbe
from models.phantom import load_phantom
from nodes.drivers.fibre_sim import SimFibreDriver

REPO = __import__("pathlib").Path(__file__).resolve().parent.parent
FLAT = load_phantom(REPO / "phantoms" / "flat_26k.yaml")
DOME = load_phantom(REPO / "phantoms" / "airfloat_tumours.yaml")


class HalfSpace:
    """Test double of the world: Hertz depth on a half-space of the phantom's background modulus."""

    def __init__(self, e_kpa: float) -> None:
        self.e = e_kpa / 1000.0  # N/mm^2
        self.calls = 0

    def depth_mm(self, x: ArrayLike, y: ArrayLike, force_n: ArrayLike, *, indenter_radius_mm: float = 4.0) -> ArrayLike:
        f = np.clip(np.asarray(force_n, dtype=float), 0.0, None)
        return np.asarray((3 * f * 0.75 / (4 * self.e * np.sqrt(indenter_radius_mm))) ** (2 / 3))

    def force_n(self, x: ArrayLike, y: ArrayLike, depth_mm: ArrayLike, *, indenter_radius_mm: float = 4.0) -> ArrayLike:
        self.calls += 1
        return np.asarray(4 * self.e * np.sqrt(indenter_radius_mm) * np.asarray(depth_mm) ** 1.5 / (3 * 0.75))


def driver(phantom=FLAT, errors: ProbeErrors | None = None, world: HalfSpace | None = None) -> SimFibreDriver:  # type: ignore[no-untyped-def]
    return SimFibreDriver(phantom, lambda: 0, errors=errors or ProbeErrors.ideal(),
                          world=world or HalfSpace(26.4))


def d_in(h: np.ndarray) -> np.ndarray:
    return np.asarray(indentation_from_heights(h[:, 0], h[:, 1], h[:, 2], h[:, 3])[0])


def test_ideal_device_on_a_flat_sample_reads_the_worlds_depth() -> None:
    w = HalfSpace(26.4)
    drv = driver(world=w)
    p = np.array([34.0, 36.0, 40.0])
    h = drv.heights(np.full(3, 30.0), np.full(3, 30.0), np.full(3, 21.0), p)
    f = 7.59 * p / 100 - 2.34  # the ideal device's force law: the paper's line
    assert d_in(h) == pytest.approx(np.asarray(w.depth_mm(p, p, f)), abs=1e-9)
    assert w.calls > 0


def test_the_driver_never_uses_the_estimators_models(monkeypatch: pytest.MonkeyPatch) -> None:
    """Contact laws (eq. 6-8) and the eq. 4 calibration object are the estimator's: the sim must not touch them."""
    def boom(*a: object, **k: object) -> None:
        raise AssertionError("the sim used an estimator model")

    for name in ("corrected_depth", "corrected_force", "hertz_depth", "corrected_modulus"):
        monkeypatch.setattr(models.contact, name, boom)
    monkeypatch.setattr(ForceCalibration, "force_n", boom)
    driver(errors=ProbeErrors.draw(1)).heights(np.full(4, 30.0), np.full(4, 30.0), np.full(4, 21.0),
                                                np.full(4, 36.0))


def test_sps_air_gap_makes_eqs_1_to_3_over_read_the_depth() -> None:
    gap = 0.05
    errs = ProbeErrors(sps_gap_mm=(gap, gap, gap))
    w = HalfSpace(26.4)
    h = driver(errors=errs, world=w).heights(np.array([30.0]), np.array([30.0]), np.array([21.0]), np.array([36.0]))
    truth = float(w.depth_mm(0.0, 0.0, 7.59 * 0.36 - 2.34))
    assert d_in(h)[0] - truth == pytest.approx(gap, abs=1e-6)  # the SPS plane sits `gap` above the tissue


def test_bore_friction_makes_a_hysteresis_loop() -> None:
    """Pressure up then down: at the same pressure the indenter sits deeper on the way down (it sticks)."""
    drv = driver(errors=ProbeErrors(friction_n=0.03))
    up = np.linspace(32.0, 40.0, 41)
    p = np.concatenate([up, up[::-1]])
    h = drv.heights(np.full(p.size, 30.0), np.full(p.size, 30.0), np.full(p.size, 21.0), p)
    d = d_in(h)
    rising, falling = d[:41], d[41:][::-1]
    assert np.all(falling >= rising - 1e-12) and np.max(falling - rising) > 0.05


def test_heights_follow_the_dome_not_a_plane() -> None:
    """Over the dome's flank the three SPS read the curved surface; eqs. 1-3's plane then differs from the true
    surface under the indenter, which the estimator has to live with."""
    w = HalfSpace(26.4)
    x, y, z = np.array([30.0]), np.array([12.0]), np.array([5.0])
    h = driver(DOME, world=w).heights(x, y, z, np.array([36.0]))
    surf = [z[0] - float(DOME.surface_z(30.0 + dx, 12.0 - dy)) for dx, dy in ((0, 6), (-5.196, -3), (5.196, -3))]
    assert h[0, :3] == pytest.approx(surf, abs=1e-6)
    truth = float(w.depth_mm(30.0, 12.0, 7.59 * 0.36 - 2.34))
    assert abs(d_in(h)[0] - truth) > 0.005  # plane-versus-surface error of a real probe on a curved top


def test_error_draws_are_seeded_and_realistic() -> None:
    a, b, c = ProbeErrors.draw(3), ProbeErrors.draw(3), ProbeErrors.draw(4)
    assert a == b and a != c
    rmse = [TrueProbe(ProbeErrors.draw(s)).eq4_residual_rmse_n() for s in range(20)]
    assert 0.025 < float(np.median(rmse)) < 0.05  # the paper's eq. 4 fit: RMSE < 0.0404 N
    assert TrueProbe(ProbeErrors.ideal()).eq4_residual_rmse_n() < 1e-9
    json.dumps(a.as_dict())  # recordable as it is


def _fibre_readings(read_every_ns: int, first_read_ns: int) -> dict[int, tuple[float, ...]]:
    """A noisy sim probe over a pose ramp (one pose per ms), read every ``read_every_ns`` from ``first_read_ns``."""
    now = [0]
    drv = SimFibreDriver(FLAT, lambda: now[0], errors=ProbeErrors.draw(3, noise_mm=0.01), world=HalfSpace(26.4),
                         seed=5)
    drv.open()
    out: dict[int, tuple[float, ...]] = {}
    for ms in range(400):
        drv.set_pose(ms * 1_000_000, 30.0, 30.0, 24.0 - ms * 0.002)
        drv.set_pressure(ms * 1_000_000, 36.0)
        now[0] = ms * 1_000_000
        if now[0] >= first_read_ns and (now[0] - first_read_ns) % read_every_ns == 0:
            out.update({s.stamp_ns: s.heights_mm for s in drv.read()})
    return out


def test_the_sim_probe_reports_the_same_at_the_same_simulated_time_however_it_is_read() -> None:
    """Sample times and noise depend on simulated time and the seed, not on when or how often the node reads the
    driver (a composed run and a multi-process one read it at other instants)."""
    a, b = _fibre_readings(1_000_000, 3_000_000), _fibre_readings(37_000_000, 20_000_000)
    common = sorted(set(a) & set(b))
    assert len(common) > 150
    assert all(a[t] == b[t] for t in common)
    assert len({a[t] for t in common}) == len(common)


def _pressure_readings(poll_every_ms: int) -> dict[int, float]:
    from nodes.drivers.pressure_sim import SimPressureDriver

    now = [0]
    drv = SimPressureDriver(lambda: now[0], 60.0, noise_kpa=0.05, tracking_kpa=0.25, seed=7)
    drv.open()
    out = {}
    for ms in range(0, 3000):
        now[0] = 1_000_000_000 + ms * 1_000_000
        if ms == 100:
            drv.set_setpoint(36.0)
        if ms % poll_every_ms == 0 or ms % 50 == 0:
            r = drv.read()
            assert r is not None
            if ms % 50 == 0:
                out[ms] = r.measured_kpa
    return out


def test_the_sim_regulator_wanders_the_same_however_often_it_is_polled() -> None:
    """The outlet's wander and the read-back noise follow simulated time and the seed, not the number of polls."""
    a, b = _pressure_readings(3), _pressure_readings(50)
    assert a.keys() == b.keys() and all(a[k] == pytest.approx(b[k], abs=1e-9) for k in a)  # the plant's float steps
    assert len({round(v, 6) for ms, v in a.items() if ms > 1000}) > 30


def test_the_sim_probe_reads_only_as_far_as_it_knows_the_arms_pose() -> None:
    """On a wall clock a starved node hears the arm's poses late: the probe pressed 5 mm into the tissue at 0.3 s
    but its node has heard poses only up to 0.1 s (the arm above it) at 0.6 s. The sensor makes its samples only as
    far as the pose is known (as the simulated camera does, 268f346), never at the arm where it was; once the late
    poses come in, the samples of the press show it pressed. A pose stream stalled for more than 1 s: the sensor
    streams on."""
    now = [0]
    drv = SimFibreDriver(FLAT, lambda: now[0], errors=ProbeErrors.ideal(), world=HalfSpace(26.4))
    drv.open()
    drv.set_pressure(0, 36.0)
    drv.set_pose(0, 30.0, 30.0, 45.0)  # above the 20 mm thick sample, out of the sensors' reach
    assert len(drv.read()) == 1  # the sensor starts
    for ms in range(10, 101, 10):
        drv.set_pose(ms * 1_000_000, 30.0, 30.0, 45.0)
    now[0] = 600_000_000
    early = drv.read()
    assert early and max(s.stamp_ns for s in early) <= 100_000_000  # not a stale arm at 0.1-0.6 s
    for ms in range(300, 601, 10):  # the late poses: pressed in from 0.3 s (face 1 mm over the surface)
        drv.set_pose(ms * 1_000_000, 30.0, 30.0, 21.0)
    late = drv.read()
    pressed = [s for s in late if s.stamp_ns >= 300_000_000]
    assert pressed and max(s.stamp_ns for s in late) == 600_000_000
    assert all(s.heights_mm[3] < 5.0 for s in pressed)  # the sensors reach the tissue: a press, not air
    now[0] = 2_000_000_000  # no pose for 1.4 s: the sensor streams on at its last pose (held for 1 s)
    assert drv.read()


def test_a_huge_time_step_is_skipped_not_allocated() -> None:
    """A clock that jumped (a forged tick an hour ahead, or at 2^63-1) or a node starved for minutes: the sim
    sensor makes at most 2 s of samples in one read and counts the rest as skipped; the regulator's wander steps
    the gap at once."""
    from nodes.drivers.pressure_sim import SimPressureDriver

    now = [1_000_000_000]
    drv = SimFibreDriver(FLAT, lambda: now[0], errors=ProbeErrors.ideal(), world=HalfSpace(26.4))
    drv.open()
    drv.set_pose(now[0], 30.0, 30.0, 45.0)
    drv.read()
    for jump in (3600 * 10**9, 2**62):
        skipped = drv.skipped
        now[0] += jump
        drv.set_pose(now[0], 30.0, 30.0, 45.0)
        got = drv.read()
        assert 0 < len(got) <= 1001 and 0 <= now[0] - got[-1].stamp_ns < 2_000_000
        assert abs(drv.skipped - skipped - (jump - 2 * 10**9) // 2_000_000) <= 1  # all but the last 2 s (500 Hz)
    reg = SimPressureDriver(lambda: now[0], 60.0, noise_kpa=0.05, tracking_kpa=0.25, seed=7)
    reg.open()
    reg.set_setpoint(36.0)
    now[0] += 2**62
    r = reg.read()
    assert r is not None and 0.0 <= r.measured_kpa <= 60.0


def _depths_one_by_one(drv: SimFibreDriver, x: np.ndarray, y: np.ndarray, force: np.ndarray,
                       reach: np.ndarray) -> np.ndarray:
    """The driver's inversion as it was written before it took a cell's samples in one call: one np.interp per sample."""
    import math

    drv._world_depth(x, y, force, reach)  # fills the curves of the cells
    d = np.zeros(x.size)
    for i in range(x.size):
        if force[i] <= 0:
            continue
        ld, lf = drv._curves[(int(np.round(x[i] / 0.5)), int(np.round(y[i] / 0.5)))]
        lfi = math.log(force[i])
        if lfi <= lf[0]:
            d[i] = math.exp(ld[0] + (lfi - lf[0]) / 1.5)
        elif lfi >= lf[-1]:
            d[i] = math.exp(ld[-1] + (lfi - lf[-1]) / 1.5)
        else:
            d[i] = math.exp(float(np.interp(lfi, lf, ld)))
    return np.minimum(d, reach)


def test_a_cells_samples_inverted_together_give_each_samples_depth_to_the_bit() -> None:
    """Runs of samples in one cell, cells revisited, forces of zero, below the first rung and past the last."""
    rng = np.random.default_rng(7)
    drv = driver(phantom=DOME)
    x = np.concatenate([np.full(40, 20.1), np.linspace(20.0, 26.0, 300), rng.uniform(10, 50, 200), np.full(5, 20.1)])
    y = np.concatenate([np.full(40, 30.2), np.linspace(30.0, 31.0, 300), rng.uniform(10, 50, 200), np.full(5, 30.2)])
    force = rng.uniform(-0.1, 3.0, x.size) * rng.choice([1e-4, 1.0, 30.0], x.size)
    reach = rng.uniform(0.5, 10.0, x.size)
    got = drv._world_depth(x, y, force, reach)
    want = _depths_one_by_one(driver(phantom=DOME), x, y, force, reach)
    assert np.array_equal(got, want)
    assert (got == 0).any() and drv._range_warned  # forces of zero, and presses past the tables, were in it
