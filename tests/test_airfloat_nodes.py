"""The air-float probe's three nodes on the in-memory bus: reader, regulator, estimator (issue 6 acceptance
in-process; the launch file runs the same graph as processes in tests/test_launch_smoke.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from messages import PressureCommand, ProbeHeights, RobotPose, StiffnessSample
from nodes.fibre_reader import FibreReader
from nodes.pressure_controller import PressureController
from nodes.static_pose import StaticPose
from nodes.stiffness_estimator import StiffnessEstimator
from palpa.testing import GraphHarness, NodeHarness


def measured(phantom: str) -> str:
    """The shipped measured-geometry file of a phantom: all the estimator may know of its thickness."""
    return phantom.replace("phantoms/", "phantoms/measured/")


def held_probe(phantom: str, kpa: float, **est: object) -> GraphHarness:
    g = GraphHarness()
    g.add(StaticPose, {"z_mm": 21.0})
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": kpa})
    g.add(FibreReader, {"phantom": phantom})
    g.add(StiffnessEstimator, {"geometry": measured(phantom), **est})
    return g


@pytest.mark.parametrize(("phantom", "truth", "pressures"), [
    ("phantoms/flat_26k.yaml", 26.4, (33.0, 36.0, 40.0)),
    ("phantoms/flat_10k.yaml", 10.8, (32.0, 33.5, 34.5)),
])
def test_estimate_within_10_percent_at_1_to_3_mm(phantom: str, truth: float, pressures: tuple[float, ...]) -> None:
    depths = []
    for kpa in pressures:
        g = held_probe(phantom, kpa)
        g.advance(1.5)
        recent = [m for m in g.published("stiffness/sample", StiffnessSample) if m.stamp_ns > g.clock.now_ns() - 5e8]
        valid = [m for m in recent if m.valid]
        assert len(valid) > 0.9 * len(recent) > 100
        d = float(np.median([m.d_in_mm for m in valid]))
        e = float(np.median([m.value for m in valid]))
        depths.append(d)
        assert abs(e / truth - 1) < 0.10, (kpa, d, e)
        g.close()
    assert min(depths) < 1.6 and max(depths) > 2.5  # the pressures span the 1-3 mm range


def test_ramp_mode_fits_three_models() -> None:
    g = GraphHarness()
    g.add(StaticPose, {"z_mm": 21.0})
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 30.0})  # just below contact force
    g.add(FibreReader, {"phantom": "phantoms/flat_26k.yaml"})
    g.add(StiffnessEstimator, {"geometry": "phantoms/measured/flat_26k.yaml", "ramp_fits": True, "max_depth_mm": 3.2})
    g.advance(1.0)
    g.publish("pressure/command", PressureCommand(mode="ramp", setpoint_kpa=40.0, rate_kpa_s=4.0))
    g.advance(2.0)
    assert not g.published("stiffness/fit")  # still ramping
    g.advance(1.5)
    fits = g.published("stiffness/fit")
    assert len(fits) == 1
    f = fits[0]
    assert abs(f.e_corrected_kpa / 26.4 - 1) < 0.1
    # the paper's Fig. 11b: Hertz overestimates the thickness-corrected value by ~22-24 % at d/r = 5
    assert 1.1 < f.e_hertz_kpa / f.e_corrected_kpa < 1.3
    assert abs(f.e_fung_kpa / f.e_corrected_kpa - 1) < 0.15
    assert f.points > 50


def test_pressure_never_exceeds_cap_whatever_is_commanded() -> None:
    h = NodeHarness(PressureController, {"max_kpa": 30.0, "startup": "hold", "setpoint_kpa": 25.0})
    for cmd in (PressureCommand(mode="hold", setpoint_kpa=1e6),
                PressureCommand(mode="ramp", setpoint_kpa=99.0, rate_kpa_s=1000.0)):
        h.publish("pressure/command", cmd)
        h.advance(2.0)
    states = h.published("pressure/state")
    assert max(s.setpoint_kpa for s in states) <= 30.0
    assert max(s.measured_kpa for s in states) <= 30.0 + 0.1  # read-back noise only
    assert "clamped" in states[-1].faults


def test_stuck_valve_raises_tracking_fault_and_vents() -> None:
    h = NodeHarness(PressureController, {"startup": "hold", "setpoint_kpa": 20.0, "tracking_timeout_s": 0.5})
    h.advance(1.0)
    h.node.driver.stuck_at_kpa = 5.0  # type: ignore[attr-defined]
    h.advance(1.0)
    last = h.published("pressure/state")[-1]
    assert "tracking_error" in last.faults and last.mode == "vent" and last.setpoint_kpa == 0.0


def test_lost_device_is_a_fault() -> None:
    h = NodeHarness(PressureController, {"startup": "hold", "setpoint_kpa": 20.0})
    h.advance(0.5)
    h.node.driver.lost = True  # type: ignore[attr-defined]
    h.advance(1.0)
    assert "device_lost" in h.published("pressure/state")[-1].faults
    h.node.driver.lost = False  # type: ignore[attr-defined]
    h.advance(0.5)
    assert "device_lost" not in h.published("pressure/state")[-1].faults


def test_samples_matched_by_stamp_and_stale_pose_is_invalid() -> None:
    h = NodeHarness(StiffnessEstimator, {"thickness_mm": 20.0, "max_wait_s": 0.2})
    t0 = h.clock.now_ns()
    from messages import PressureState

    # heights arrive BEFORE the pose/force that bracket them: they must wait, then be matched by stamp
    hm = ProbeHeights(stamp_ns=t0 + 5_000_000, seq=1, h_mm=(1.0, 1.0, 1.0, 3.0), raw=(0, 0, 0, 0),
                      d_in_mm=2.0, tilt_rad=0.0)
    h.publish("probe/heights", hm)
    h.advance(0.02)
    assert not h.published("stiffness/sample")
    for k, x in ((0, 10.0), (10_000_000, 20.0)):
        h.publish("robot/pose", RobotPose(stamp_ns=t0 + k, x_mm=x, y_mm=0.0, z_mm=21.0))
        h.publish("pressure/state", PressureState(stamp_ns=t0 + k, setpoint_kpa=36, measured_kpa=36,
                                                  force_n=0.4, mode="hold", max_kpa=60))
    h.advance(0.05)
    s = h.published("stiffness/sample")[0]
    assert s.valid and math.isclose(s.x_mm, 15.0)  # interpolated at the sample's stamp
    # a sample far past the last pose: stale
    h.publish("probe/heights", ProbeHeights(stamp_ns=t0 + 900_000_000, seq=2, h_mm=(1.0, 1.0, 1.0, 3.0),
                                            raw=(0, 0, 0, 0), d_in_mm=2.0, tilt_rad=0.0))
    h.advance(1.5)
    assert h.published("stiffness/sample")[-1].reason == "stale_pose"


def test_fibre_sim_rate_and_no_contact_when_lifted() -> None:
    g = GraphHarness()
    pose = g.add(StaticPose, {"z_mm": 40.0})  # 20 mm above a 20 mm thick phantom: beyond the stroke
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 36.0})
    g.add(FibreReader, {"phantom": "phantoms/flat_26k.yaml", "rate_hz": 500.0})
    g.add(StiffnessEstimator, {"thickness_mm": 20.0})
    g.advance(1.0)
    heights = g.published("probe/heights")
    assert 480 <= len(heights) <= 520
    assert {m.reason for m in g.published("stiffness/sample")} == {"no_contact"}
    assert pose.params.z_mm == 40.0


def test_airfloat_sim_launch_estimates_10k_phantom(procs, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Issue 6 acceptance as processes: launch/airfloat_sim.yaml over the 10.8 kPa phantom."""
    from launching import launched, spin_until

    with launched(procs, "launch/airfloat_sim.yaml", tmp_path / "run", "phantom:=phantoms/flat_10k.yaml",
                  "pressure_kpa:=33.5") as (proc, node):
        samples = node.subscribe("stiffness/sample", StiffnessSample)
        got: list[StiffnessSample] = []

        def enough() -> bool:
            while samples.queue:
                m = samples.queue.popleft()
                if m.valid:
                    got.append(m)
            return len(got) >= 300

        spin_until(node, enough, 60, "300 valid samples", proc)
    e = float(np.median([m.value for m in got[-200:]]))
    d = float(np.median([m.d_in_mm for m in got[-200:]]))
    assert 1.0 <= d <= 3.0 and abs(e / 10.8 - 1) < 0.10, (d, e)
