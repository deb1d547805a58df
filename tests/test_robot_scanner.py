"""Robot scanner safety and progress, on the simulated arm (deterministic, mock clock)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

import palpa
from messages import (
    EStop,
    PressureState,
    ProbeAt,
    ProbeHeights,
    ProbeResult,
    Trigger,
    TriggerResult,
)
from nodes.scanner.robot_scanner import RobotScanner
from palpa.node.service import RequestRefused
from palpa.testing import NodeHarness

SMALL: dict[str, Any] = {"region_mm": [10, 10, 20, 20], "spacing_mm": 5, "speed_mm_s": 20, "home_mm": [10, 10, 20]}


def heights(h: NodeHarness[RobotScanner]) -> None:
    h.publish("probe/heights", ProbeHeights(stamp_ns=h.clock.now_ns(), seq=0, h_mm=(1, 1, 1, 2), raw=(0, 0, 0, 0),
                                            d_in_mm=1.0, tilt_rad=0.0))


def run_with_probe(h: NodeHarness[RobotScanner], seconds: float, step: float = 0.002) -> None:
    for _ in range(int(seconds / step)):
        heights(h)
        h.advance(step)


def speed(h: NodeHarness[RobotScanner]) -> float:
    return float(h.published("robot/pose")[-1].speed_mm_s)


def test_scan_completes_with_progress_and_exit_0() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    plan = h.published("robot/plan")
    assert len(plan) == 1 and plan[0].lines == 3 and plan[0].waypoints  # latched plan before any motion
    assert h.published("robot/scan_status")[-1].state == "waiting"
    seen_progress = []
    for _ in range(200):
        run_with_probe(h, 0.1)
        st = h.published("robot/scan_status")[-1]
        seen_progress.append(st.progress)
        if h.node.is_shutdown:
            break
    assert h.node.is_shutdown and h.node.exit_code == 0
    assert st.state == "done" and st.progress == 1.0 and st.eta_s == 0.0
    assert seen_progress == sorted(seen_progress) and 0 < seen_progress[len(seen_progress) // 2] < 1
    poses = h.published("robot/pose")
    rate = len(poses) / ((poses[-1].stamp_ns - poses[0].stamp_ns) / 1e9)
    assert rate >= 125


def test_plan_leaving_the_box_is_refused_before_motion() -> None:
    with pytest.raises(palpa.ParamError, match=r"before any motion: the scan region \(region_mm\) x 10\.\.80, y "
                                               r"10\.\.20 mm does not fit the workspace box \(x -10\.\.70, y -10\.\.70, "
                                               r"z 0\.5\.\.60 mm\): x 80 > x_max 70"):
        NodeHarness(RobotScanner, {**SMALL, "region_mm": [10, 10, 80, 20]})


def test_speed_over_cap_is_refused() -> None:
    with pytest.raises(palpa.ParamError, match=r"waypoint \d+ .* asks 80 mm/s.* over the caps 50 mm/s"):
        NodeHarness(RobotScanner, {**SMALL, "speed_mm_s": 80.0})


def test_start_outside_the_box_is_refused() -> None:
    with pytest.raises(palpa.ParamError, match="current pose is outside the workspace box"):
        NodeHarness(RobotScanner, {**SMALL, "home_mm": [10, 10, 65]})


def moving(h: NodeHarness[RobotScanner]) -> None:
    for _ in range(300):
        run_with_probe(h, 0.05)
        if speed(h) > 15:
            return
    raise AssertionError("the arm never got up to speed")


def test_stale_probe_data_stops_the_arm_within_100_ms() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    moving(h)
    stale_from = h.clock.now_ns()
    h.advance(0.1)  # no more probe data
    st = h.published("robot/scan_status")[-1]
    assert st.state == "fault" and "stale" in st.message
    last = h.published("robot/pose")[-1]  # the pose stream runs at 250 Hz: the last one is within 4 ms
    assert stale_from + 96_000_000 <= last.stamp_ns <= stale_from + 100_000_000 and last.speed_mm_s == 0.0
    h.advance(1.0)
    assert h.node.exit_code == 1


def test_pressure_fault_stops_the_arm() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    moving(h)
    h.publish("pressure/state", PressureState(stamp_ns=h.clock.now_ns(), setpoint_kpa=0, measured_kpa=70,
                                              force_n=0, mode="vent", max_kpa=60, faults=["over_pressure"]))
    run_with_probe(h, 0.1)
    st = h.published("robot/scan_status")[-1]
    assert st.state == "fault" and "over_pressure" in st.message and speed(h) == 0.0


def test_estop_stops_at_once() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    moving(h)
    h.publish("robot/estop", EStop(stamp_ns=h.clock.now_ns(), reason="operator"))
    assert h.published("robot/scan_status")[-1].state == "estop"  # in the same callback
    run_with_probe(h, 0.05)  # 20 mm/s at 1000 mm/s^2 stops in 20 ms
    assert speed(h) == 0.0
    pose = h.published("robot/pose")[-1]
    run_with_probe(h, 0.2)
    assert math.isclose(h.published("robot/pose")[-1].x_mm, pose.x_mm)


def test_no_probe_data_at_start_is_a_fault_without_motion() -> None:
    h = NodeHarness(RobotScanner, {**SMALL, "startup_timeout_s": 1.0})
    h.advance(1.5)
    st = h.published("robot/scan_status")[-1]
    assert st.state == "fault" and "no probe data" in st.message
    assert all(p.speed_mm_s == 0.0 for p in h.published("robot/pose"))


def test_indent_mode_holds_at_each_point() -> None:
    h = NodeHarness(RobotScanner, {**SMALL, "mode": "indent", "spacing_mm": 10, "contact_z_mm": 10.0,
                                   "indent_depth_mm": 3.0, "hold_s": 0.3, "watch_topic": "", "speed_mm_s": 10.0})
    plan = h.published("robot/plan")[0]
    presses = [w for w in plan.waypoints if w.kind == "hold"]
    assert len(presses) == 4 and all(w.z_mm == 7.0 and w.hold_s == 0.3 for w in presses)
    low = []
    for _ in range(400):
        h.advance(0.05)
        p = h.published("robot/pose")[-1]
        if p.z_mm < 7.01:
            low.append(p.stamp_ns)
        if h.node.is_shutdown:
            break
    assert h.node.exit_code == 0
    assert (max(low) - min(low)) / 1e9 > 4 * 0.3  # it dwelt at the press depth at every point


def pressure(h: NodeHarness[RobotScanner]) -> None:
    h.publish("pressure/state", PressureState(stamp_ns=h.clock.now_ns(), setpoint_kpa=36, measured_kpa=36,
                                              force_n=1, mode="hold", max_kpa=60))


def test_pressure_state_going_quiet_stops_the_arm() -> None:
    h = NodeHarness(RobotScanner, {**SMALL, "pressure_watchdog_s": 0.2})
    moving(h)  # no pressure/state heard yet: not watched (a scanner without a pressure controller)
    for _ in range(50):
        pressure(h)
        run_with_probe(h, 0.02)
    assert h.published("robot/scan_status")[-1].state == "scanning"
    quiet_from = h.clock.now_ns()
    run_with_probe(h, 0.3)  # probe data keeps coming; the pressure controller is dead
    st = h.published("robot/scan_status")[-1]
    assert st.state == "fault" and "pressure/state silent" in st.message and speed(h) == 0.0
    poses = h.published("robot/pose")
    assert any(p.speed_mm_s > 15 for p in poses if quiet_from < p.stamp_ns < quiet_from + 200_000_000)
    assert all(p.speed_mm_s == 0.0 for p in poses if p.stamp_ns > quiet_from + 240_000_000)


def test_stale_data_fails_the_probe_not_the_scanner_and_the_next_probe_lifts_first() -> None:
    """A probe is a service call: data going stale on its path stops the arm and fails that call with the reason,
    and the scanner stays up. It refuses probes while the data is stale; the first after it lifts the arm straight
    up from where it stopped (the probe may still touch the tissue) before it moves across."""
    h = NodeHarness(RobotScanner, {**SMALL, "autostart": False, "pressure_watchdog_s": 0.2, "contact_z_mm": 5.0})
    probe = h.add(palpa.Node, name="caller").client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60)

    def fresh(seconds: float) -> None:
        for _ in range(round(seconds / 0.01)):
            heights(h)
            pressure(h)
            h.advance(0.01)

    fresh(0.1)
    first = probe.call_async(ProbeAt(x_mm=15.0, y_mm=15.0))
    for _ in range(1000):
        fresh(0.01)
        if h.published("robot/pose")[-1].z_mm < 5.01 and speed(h) > 5:  # sliding along the line at its height
            break
    else:
        raise AssertionError("the probe never reached its line")
    run_with_probe(h, 0.3)  # the probe's data goes on; the pressure controller is silent
    with pytest.raises(RequestRefused, match="the scanner stopped the arm.*pressure/state silent"):
        first.result()
    st = h.published("robot/scan_status")[-1]
    assert st.state == "idle" and "pressure/state silent" in st.message and speed(h) == 0.0
    assert not h.node.is_shutdown
    stopped = h.published("robot/pose")[-1]
    refused = probe.call_async(ProbeAt(x_mm=12.0, y_mm=12.0))
    run_with_probe(h, 0.1)
    with pytest.raises(RequestRefused, match="no fresh data to move on: pressure/state silent"):
        refused.result()
    assert h.published("robot/pose")[-1].x_mm == stopped.x_mm and speed(h) == 0.0
    fresh(0.1)
    n = len(h.published("robot/pose"))
    after = probe.call_async(ProbeAt(x_mm=12.0, y_mm=12.0))
    for _ in range(300):  # the answer waits up to 10 s for an estimate
        fresh(0.1)
        if after.done():
            break
    assert after.done()
    with pytest.raises(RequestRefused, match="no valid stiffness estimate"):  # no estimator in this graph
        after.result()
    poses = h.published("robot/pose")[n:]
    up = next(i for i, q in enumerate(poses) if q.z_mm > 19.99)  # the retract height: contact_z_mm + 15 mm
    assert up > 0 and all(math.dist((q.x_mm, q.y_mm), (stopped.x_mm, stopped.y_mm)) < 1e-6 for q in poses[:up])
    assert min(math.dist((q.x_mm, q.y_mm), (12.0, 12.0 - 3.0)) for q in poses) < 0.01  # then the new line's start
    assert h.published("robot/scan_status")[-1].state == "idle" and not h.node.is_shutdown


def test_with_a_stale_hold_a_scan_waits_for_its_data_then_goes_on_or_ends_when_it_stays_away() -> None:
    """stale_hold_s: a scan whose pressure controller goes quiet stops and holds, paused, without moving; data
    fresh again, it goes on along its line and completes, the hold counted in its final status. Quiet for longer
    than the hold, the scan ends as a fault. An operator's resume is refused while the data is stale."""
    for back_after_s, code in ((0.5, 0), (1.5, 1)):
        h = NodeHarness(RobotScanner, {**SMALL, "pressure_watchdog_s": 0.2, "stale_hold_s": 1.0})
        resume = h.add(palpa.Node, name="operator").client("scanner/resume", Trigger, TriggerResult)
        for _ in range(300):  # up to speed, with the pressure controller heard
            pressure(h)
            run_with_probe(h, 0.02)
            if speed(h) > 15:
                break
        run_with_probe(h, 0.3)  # the pressure controller is silent
        st = h.published("robot/scan_status")[-1]
        assert st.state == "paused" and st.message.startswith("held: pressure/state silent") and speed(h) == 0.0
        stopped = h.published("robot/pose")[-1]
        refused = resume.call_async(Trigger())
        run_with_probe(h, back_after_s - 0.3)
        with pytest.raises(RequestRefused, match="not resuming on stale data"):
            refused.result()
        held = [q for q in h.published("robot/pose") if q.stamp_ns > stopped.stamp_ns]
        if code:
            st = h.published("robot/scan_status")[-1]
            assert st.state == "fault" and "not fresh again within the 1 s hold" in st.message
            assert all(q.x_mm == stopped.x_mm and q.y_mm == stopped.y_mm for q in held)
            h.advance(1.0)
            assert h.node.exit_code == 1
            continue
        assert all(q.x_mm == stopped.x_mm and q.y_mm == stopped.y_mm and q.z_mm == stopped.z_mm for q in held)
        for _ in range(2000):  # the pressure controller is back
            pressure(h)
            run_with_probe(h, 0.02)
            if h.node.is_shutdown:
                break
        states = [k for k, _ in itertools.groupby(s.state for s in h.published("robot/scan_status"))]
        assert states[states.index("paused"):] == ["paused", "scanning", "done"]  # it went on, once
        assert h.node.exit_code == 0 and h.published("robot/scan_status")[-1].message.endswith(
            "(held 1 time(s) for stale data)")


def test_an_estop_or_abort_during_a_stale_hold_ends_the_scan_and_fresh_data_does_not_move_the_arm_again() -> None:
    """A hold waits for the data to resume the scan; an e-stop or an abort meanwhile ends it for good: the data
    coming back afterwards must not start the arm again."""
    for end in ("estop", "abort"):
        h = NodeHarness(RobotScanner, {**SMALL, "pressure_watchdog_s": 0.2, "stale_hold_s": 5.0, "linger_s": 2.0})
        abort = h.add(palpa.Node, name="operator").client("scanner/abort", Trigger, TriggerResult)
        for _ in range(300):
            pressure(h)
            run_with_probe(h, 0.02)
            if speed(h) > 15:
                break
        run_with_probe(h, 0.3)  # the pressure controller is silent: held
        assert h.published("robot/scan_status")[-1].state == "paused"
        if end == "estop":
            h.publish("robot/estop", EStop(stamp_ns=h.clock.now_ns(), reason="operator"))
        else:
            fut = abort.call_async(Trigger())
            h.spin()
            assert fut.result().state == "stopped"
        stopped = h.published("robot/pose")[-1]
        for _ in range(50):  # the pressure controller is back, while the scanner lingers
            pressure(h)
            run_with_probe(h, 0.02)
        after = [q for q in h.published("robot/pose") if q.stamp_ns > stopped.stamp_ns]
        assert after and all((q.x_mm, q.y_mm, q.z_mm) == (stopped.x_mm, stopped.y_mm, stopped.z_mm) for q in after)
        assert h.published("robot/scan_status")[-1].state == ("estop" if end == "estop" else "stopped")
