"""Our UR driver, and the rig's scan graph around it, on the emulated controller in process (emulators.ur.local):
driver, graph and arm share one simulated clock, so these run in the in-process tier, deterministic, with no wall-clock
wait. ur_rtde itself, over TCP to the emulator's server, is tested in the system tier (test_robot_drivers.py,
test_ur_emulator.py)."""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import palpa
from emulators.ur.controller import ControllerConfig, FaultPlan, UrController
from emulators.ur.local import LocalUr, hosts
from messages import RobotPose, ScanPlan
from models.arm import ArmTarget
from nodes.drivers.robot import MotionStatus, PathPoint, RobotConnectionError, RobotDriverError
from nodes.drivers.robot_urrtde import URRtdeDriver
from nodes.scanner.robot_scanner import RobotScanner
from nodes.scanner.scan_supervision import SUPERVISION_MAX_S
from palpa.testing import GraphHarness
from palpa.timing.clock import MockClock

HOME = (2.0, 2.0, 20.0, 0.0, math.pi, 0.0)
"""The emulated arm's home (mm, rad, base frame): launch/scan_ur.yaml's home_mm, the frame offset being zero."""
LINE = [PathPoint(10.0, 2.0, 20.0, 20.0, 500.0), PathPoint(40.0, 2.0, 5.0, 20.0, 500.0),
        PathPoint(40.0, 8.0, 5.0, 20.0, 500.0), PathPoint(10.0, 8.0, 5.0, 20.0, 500.0)]
"""A raster's first line and the step to the next, at 20 mm/s."""
STEP_S = 0.01


RIG_HOME = (19.0, 19.0, 8.0, 0.0, math.pi, 0.0)
"""The arm's start for the graph's tests: near the raster, so that little simulated time goes to the approach."""


@pytest.fixture
def ur(request: pytest.FixtureRequest) -> Iterator[tuple[MockClock, UrController]]:
    """An emulated controller served as ``ur-local`` on a mock clock, at HOME (or the home a test's indirect
    parameter names)."""
    clock = MockClock()
    ctl = UrController(ControllerConfig(home_pose=getattr(request, "param", HOME)))
    with hosts.serving("ur-local", LocalUr(ctl, clock.now_ns)):
        yield clock, ctl


at_the_rig_s_start = pytest.mark.parametrize("ur", [RIG_HOME], indirect=True, ids=["rig-home"])


def driver(clock: MockClock, watchdog_hz: float | None = 2.0) -> URRtdeDriver:
    drv = URRtdeDriver("ur-local", watchdog_hz=watchdog_hz, clock=clock.now_ns, interfaces=hosts)
    drv.connect()
    return drv


Sample = tuple[int, MotionStatus, int, tuple[float, ...]]
"""What the driver says at one instant: (clock ns, status, waypoint, position mm)."""


def run(drv: URRtdeDriver, clock: MockClock, seconds: float) -> list[Sample]:
    """Poll the driver every STEP_S of the clock for ``seconds``, as a node's timer would."""
    out: list[Sample] = []
    for _ in range(round(seconds / STEP_S)):
        clock.advance(STEP_S)
        p, st = drv.progress(), drv.state()
        out.append((clock.now_ns(), p.status, p.index, st.pose[:3]))
    return out


def _scan_line(clock: MockClock) -> list[Sample]:
    drv = driver(clock)
    # nothing moves between the driver's calls: no monitor thread polls on the wall's time beside the caller
    assert not [t for t in threading.enumerate() if t.name.startswith("ur-monitor")]
    try:
        drv.move_path(LINE)
        return run(drv, clock, 5.0)
    finally:
        drv.close()


def _wall_racing_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    """A starved process: every read of the wall clock finds it a minute later."""
    jump = iter(range(1, 10**9))
    for name in ("monotonic", "time"):
        real = getattr(time, name)
        monkeypatch.setattr(time, name, lambda real=real: real() + 60.0 * next(jump))
    for name in ("monotonic_ns", "time_ns"):
        real_ns = getattr(time, name)
        monkeypatch.setattr(time, name, lambda real_ns=real_ns: real_ns() + 60 * 10**9 * next(jump))


def test_the_driver_follows_a_scan_line_at_its_speed_on_the_emulated_controller_s_time(
        ur: tuple[MockClock, UrController], monkeypatch: pytest.MonkeyPatch) -> None:
    clock, ctl = ur
    trace = _scan_line(clock)
    statuses = [s for _, s, _, _ in trace]
    assert statuses[0] is MotionStatus.MOVING and statuses[-1] is MotionStatus.DONE
    done_at = statuses.index(MotionStatus.DONE)
    assert set(statuses[done_at:]) == {MotionStatus.DONE}
    path = [(p.x_mm, p.y_mm, p.z_mm) for p in LINE]
    assert math.dist(trace[-1][3], path[-1]) < 1e-6
    for i, corner in enumerate(path):  # every waypoint reached, in order, and reported as reached
        near = [k for k, (_, _, _, xyz) in enumerate(trace) if math.dist(xyz, corner) < 0.01]
        assert near, f"waypoint {i} {corner} never reached"
        assert all(index >= i for _, _, index, _ in trace[near[0] + 1:])
    speeds = [math.dist(a[3], b[3]) / ((b[0] - a[0]) / 1e9) for a, b in zip(trace, trace[1:], strict=False)]
    assert max(speeds) <= 20.0 * 1.001 and max(speeds) > 19.0  # the path's speed, reached and held
    length = sum(math.dist(a, b) for a, b in zip([HOME[:3], *path], path, strict=False))
    took = (trace[done_at][0] - trace[0][0]) / 1e9 + STEP_S
    assert length / 20.0 < took < length / 20.0 + 0.5, (length, took)  # at 20 mm/s, with its accelerations
    # the same on a starved machine whose wall clock races ahead: nothing above read it
    clock2 = MockClock()
    with hosts.serving("ur-2", LocalUr(UrController(ControllerConfig(home_pose=HOME)), clock2.now_ns)):
        _wall_racing_ahead(monkeypatch)
        drv = URRtdeDriver("ur-2", watchdog_hz=2.0, clock=clock2.now_ns, interfaces=hosts)
        drv.connect()
        drv.move_path(LINE)
        again = run(drv, clock2, 5.0)
        drv.close()
    assert [(t - trace[0][0], s, i, p) for t, s, i, p in trace] == [(t - again[0][0], s, i, p) for t, s, i, p in again]


def test_a_protective_stop_is_latched_until_unlocked_on_the_controller_s_time_and_connected_again(
        ur: tuple[MockClock, UrController]) -> None:
    clock, ctl = ur
    drv = driver(clock)
    ctl.arm_faults(FaultPlan(pstop_after_waypoints=2))
    drv.move_path(LINE)
    trace = run(drv, clock, 3.0)
    p = drv.progress()
    assert p.status is MotionStatus.PROTECTIVE_STOP and "protective stop on the UR at ur-local" in p.message
    assert re.search(r"waypoint [12] of 4\)", p.message) and not ctl.arm.is_moving  # stopped after the 2nd
    stopped = next(k for k, (_, s, _, _) in enumerate(trace) if s is MotionStatus.PROTECTIVE_STOP)
    assert {s for _, s, _, _ in trace[stopped:]} == {MotionStatus.PROTECTIVE_STOP}  # latched
    with pytest.raises(RobotDriverError, match="cannot move: protective_stop"):
        drv.move_path(LINE)
    with pytest.raises(RobotConnectionError, match="is in a protective stop"):
        drv.connect()
    stop_s = trace[stopped][0] / 1e9
    assert ctl.unlock_protective_stop().startswith("Cannot unlock")  # 5 s of the controller's time, not yet
    clock.advance(stop_s + 5.0 - clock.now_ns() / 1e9 + 0.1)
    hosts._at("ur-local").sync()  # the controller runs up to the clock's now (a dashboard call would)
    assert ctl.unlock_protective_stop() == "Protective stop releasing"
    drv.connect()
    assert drv.progress().status is MotionStatus.IDLE
    drv.move_path(LINE[-1:])
    run(drv, clock, 3.0)
    assert drv.progress().status is MotionStatus.DONE and math.dist(drv.state().pose[:3], (10.0, 8.0, 5.0)) < 1e-6
    drv.close()


def test_the_rtde_watchdog_is_kicked_on_the_node_s_clock_and_starves_when_the_node_stalls(
        ur: tuple[MockClock, UrController]) -> None:
    """Polled every 10 ms of its clock the driver keeps the 2 Hz watchdog fed however little wall time passes; a
    node that stalls for a simulated second starves it, and the driver says so."""
    clock, ctl = ur
    drv = driver(clock, watchdog_hz=2.0)
    drv.move_path([PathPoint(60.0, 2.0, 20.0, 10.0, 500.0)])  # 5.8 s of motion
    trace = run(drv, clock, 3.0)
    assert {s for _, s, _, _ in trace} == {MotionStatus.MOVING} and ctl.program is not None
    clock.advance(1.0)  # the node stalls: nobody calls the driver for a simulated second
    p = drv.progress()
    assert p.status is MotionStatus.FAULT and "control script stopped" in p.message, p.message
    assert "RTDE watchdog: this driver did not kick it for 1.0" in p.message and "the 0.5 s it allows" in p.message
    assert any("RTDE watchdog: input_int_register_0 not updated" in m for m in ctl.messages)
    drv.close()


def test_an_unreachable_and_a_dropped_controller(ur: tuple[MockClock, UrController]) -> None:
    clock, ctl = ur
    with pytest.raises(RobotConnectionError, match="cannot reach the UR controller at nobody"):
        URRtdeDriver("nobody", clock=clock.now_ns, interfaces=hosts).connect()
    drv = driver(clock)
    ctl.arm_faults(FaultPlan(drop_at_s=0.3, refuse_s=1.0))
    drv.move_path(LINE)
    run(drv, clock, 0.5)
    p = drv.progress()
    assert p.status is MotionStatus.DISCONNECTED and "not reconnecting" in p.message
    with pytest.raises(RobotConnectionError, match="cannot reach"):
        drv.connect()  # refused for a second of the controller's time
    clock.advance(1.0)
    drv.connect()
    assert drv.progress().status is MotionStatus.IDLE
    drv.close()


# ----------------------------------------------------------------------------------- the rig's graph, in process
RIG = "launch/scan_ur.yaml"


def rig(tmp_path: Path, clock: MockClock) -> GraphHarness:
    """launch/scan_ur.yaml as the recipe runs it against the emulator (simulated fibre and pressure), composed on
    ``clock`` with the scanner's driver on the in-process controller at ``ur-local``: a raster of two short lines."""
    return GraphHarness.from_launch(
        RIG, run_dir=tmp_path, clock=clock, every_node=True, robot_host="ur-local", home_mm=list(RIG_HOME[:3]),
        fibre_driver="sim",
        pressure_driver="sim", phantom="phantoms/airfloat_tumours.yaml", region_mm=[20.0, 20.0, 23.0, 26.0],
        node_params={"scanner": {"rtde_interfaces": "emulators.ur.local:hosts"}, "map": {"png_helper": False}})


def _scanner(g: GraphHarness) -> RobotScanner:
    scanner = next(n for n in g.nodes if n.name == "scanner")
    assert isinstance(scanner, RobotScanner)
    return scanner


def _state(g: GraphHarness) -> str:
    return str(g.published("robot/scan_status")[-1].state)


def _advance_until(g: GraphHarness, clock: MockClock, done: Callable[[], bool], within_s: float, step_s: float,
                   what: str) -> None:
    """Advance the graph ``step_s`` at a time until ``done()``; fail naming ``what`` after ``within_s`` simulated."""
    end = clock.now_ns() + within_s * 1e9
    while not done():
        assert clock.now_ns() < end, f"{what} not within {within_s:g} simulated s: {g.published('robot/scan_status')[-1]}"
        g.advance(step_s)


def _scanning(g: GraphHarness, clock: MockClock, ctl: UrController) -> None:
    _advance_until(g, clock, lambda: _state(g) == "scanning" and ctl.arm.is_moving, 30.0, 0.05, "the scan moving")


@at_the_rig_s_start
def test_the_rig_s_scan_graph_runs_its_raster_on_the_emulated_ur_in_the_box_and_under_the_cap(
        ur: tuple[MockClock, UrController], tmp_path: Path) -> None:
    clock, ctl = ur
    with rig(tmp_path, clock) as g:
        scanner = _scanner(g)
        _advance_until(g, clock, lambda: _state(g) == "done", 60.0, 0.5, "the raster's end")
        plan: ScanPlan = g.published("robot/plan", ScanPlan)[0]
        poses: list[RobotPose] = g.published("robot/pose", RobotPose)
        samples = g.published("stiffness/sample")
        box, cap = scanner.params.workspace_mm, scanner.params.max_speed_mm_s
    xyz = [(p.x_mm, p.y_mm, p.z_mm) for p in poses]
    assert all(box[0] <= x <= box[3] and box[1] <= y <= box[4] and box[2] <= z <= box[5] for x, y, z in xyz)
    for w in plan.waypoints:  # the raster followed: each waypoint reached
        assert min(math.dist(p, (w.x_mm, w.y_mm, w.z_mm)) for p in xyz) < 0.05, w
    fastest = max(w.speed_mm_s for w in plan.waypoints)
    assert fastest <= cap
    window = round(0.1 * scanner.params.pose_rate_hz)  # speeds over 0.1 s: the 2 ms cycles do not blur them
    speeds = [math.dist(xyz[k], xyz[k + window]) / ((poses[k + window].stamp_ns - poses[k].stamp_ns) / 1e9)
              for k in range(len(poses) - window)]
    assert fastest * 0.95 < max(speeds) <= fastest * 1.02
    on_lines = [s for s in samples if s.valid]
    assert len(on_lines) > 100 and {round(s.x_mm) for s in on_lines} >= {20, 23}  # both lines palpated
    assert ctl.program is None and not ctl.arm.is_moving  # the scanner closed its driver: script stopped
    assert (tmp_path / "map" / "map.npz").is_file()  # and the map was written


@at_the_rig_s_start
def test_stale_probe_data_stops_the_emulated_arm_as_a_fault_after_the_watchdog_s_simulated_time(
        ur: tuple[MockClock, UrController], tmp_path: Path) -> None:
    clock, ctl = ur
    with rig(tmp_path, clock) as g:
        scanner = _scanner(g)
        fibre = next(n for n in g.nodes if n.name == "fibre")
        _scanning(g, clock, ctl)
        g.advance(0.5)
        fibre.request_shutdown()  # the probe's data stops (it comes every few ms until now)
        killed, watchdog = clock.now_ns(), scanner.params.watchdog_s
        g.advance(watchdog - 0.02)
        assert _state(g) == "scanning" and ctl.arm.is_moving  # not before the watchdog's time
        g.advance(0.02 + SUPERVISION_MAX_S + 0.002)
        assert (clock.now_ns() - killed) / 1e9 < watchdog + SUPERVISION_MAX_S + 0.005
        status = g.published("robot/scan_status")[-1]
        assert status.state == "fault" and "probe/heights" in status.message, status
        g.advance(0.2)
        assert not ctl.arm.is_moving  # the arm stopped by the scanner


@at_the_rig_s_start
def test_an_arm_pushed_out_of_the_workspace_box_is_stopped_as_a_fault(
        ur: tuple[MockClock, UrController], tmp_path: Path) -> None:
    """Something other than the scanner moves the arm (a pendant jog, another client): the scanner's box check on
    the poses the driver reads stops it as a fault once the TCP leaves the box."""
    clock, ctl = ur
    with rig(tmp_path, clock) as g:
        scanner = _scanner(g)
        top = scanner.params.workspace_mm[5]
        _scanning(g, clock, ctl)
        with ctl.lock:  # jogged straight up at 100 mm/s, out through the box's top
            ctl.start_motion([ArmTarget((*ctl.arm.pose[:2], top + 40.0, *ctl.arm.pose[3:]), 100.0, 2000.0)])
        _advance_until(g, clock, lambda: ctl.arm.pose[2] > top + 0.5 or _state(g) != "scanning", 2.0, 0.002,
                       "the arm leaving the box's top")
        g.advance(SUPERVISION_MAX_S + 0.002)
        status = g.published("robot/scan_status")[-1]
        assert status.state == "fault" and "outside the workspace box" in status.message, status
        g.advance(0.5)
        # stopped from 100 mm/s at the cap's deceleration, within a supervision pass and a few cycles of leaving
        stop_mm = 100.0**2 / (2 * scanner.params.max_accel_mm_s2) + 100.0 * (SUPERVISION_MAX_S + 0.006)
        assert not ctl.arm.is_moving and top + 0.5 < ctl.arm.pose[2] < top + 0.5 + stop_mm


def test_a_misspelt_rtde_interfaces_is_a_parameter_error_naming_the_closest(ur: tuple[MockClock, UrController]) -> None:
    clock, _ = ur
    g = GraphHarness(clock=clock)
    with pytest.raises(palpa.ParamError, match=r"scanner: rtde_interfaces: .*has no 'host'.*did you mean 'hosts'"):
        g.add(RobotScanner, {"driver": "ur_rtde", "robot_host": "ur-local", "rtde_interfaces": "emulators.ur.local:host",
                             "home_mm": list(HOME[:3])}, name="scanner")
    g.close()
