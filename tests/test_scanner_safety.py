"""The scanner's safety limits hold while it runs (issue 39): no run-time change widens the workspace box or a cap,
a change the scanner does not apply is refused rather than acknowledged, and a probe whose path the arm's driver
refuses ends the probe (idle again, the reason said) instead of leaving the scanner in ``probing``."""

from __future__ import annotations

from typing import Any

import pytest

import palpa
from messages import EStop, ProbeAt, ProbeResult, StiffnessSample
from nodes.drivers.robot import MotionStatus
from nodes.scanner.robot_scanner import RobotScanner
from palpa.node.params_runtime import PARAMS_TOPIC, ParamSet, ParamValues, param_service
from palpa.node.service import RequestRefused
from palpa.node.service_client import Future
from palpa.testing import GraphHarness

BOX = [-10.0, -10.0, 0.5, 70.0, 70.0, 60.0]
"""launch/probe_sim.yaml's box (the scanner's default)."""


def scanner_graph() -> tuple[GraphHarness, RobotScanner, palpa.Node]:
    g = GraphHarness()
    scanner = g.add(RobotScanner, {"autostart": False, "home_mm": [28.0, 28.0, 40.0], "watch_topic": "",
                                   "workspace_mm": BOX}, name="scanner", serve_params=True)
    op = g.add(palpa.Node, name="operator")
    g.advance(0.1)
    assert g.published("robot/scan_status")[-1].state == "idle"
    return g, scanner, op


def set_param(g: GraphHarness, op: palpa.Node, **values: Any) -> ParamValues:
    fut = op.client(param_service("scanner", "set"), ParamSet, ParamValues).call_async(ParamSet(values=values))
    g.spin()
    return fut.result()


def probe(g: GraphHarness, op: palpa.Node, x: float, y: float) -> Future[ProbeResult]:
    fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(ProbeAt(x_mm=x, y_mm=y))
    g.spin()
    return fut


def test_the_box_cannot_be_widened_at_run_time_and_a_probe_outside_it_does_not_move_the_arm() -> None:
    """The issue's exploit: widen the box with `param set`, then probe 80 mm outside the launch file's box."""
    g, scanner, op = scanner_graph()
    with pytest.raises(RequestRefused, match="'workspace_mm' is a safety limit, fixed at launch"):
        set_param(g, op, workspace_mm=[-10, -10, 0.5, 300, 300, 100])
    for cap in ({"max_speed_mm_s": 500.0}, {"max_accel_mm_s2": 10_000.0}, {"watchdog_s": 60.0},
                {"pressure_watchdog_s": 0.0}, {"watch_topic": "camera/indenters"}):
        name = next(iter(cap))
        with pytest.raises(RequestRefused, match=f"'{name}' is a safety limit"):
            set_param(g, op, **cap)
    assert list(scanner.params.workspace_mm) == BOX and g.published(PARAMS_TOPIC) == []
    before = scanner.driver.state().pose[:3]
    fut = probe(g, op, 150.0, 30.0)
    with pytest.raises(RequestRefused, match="workspace"):
        fut.result()
    g.advance(1.0)
    assert scanner.driver.state().pose[:3] == before and g.published("robot/pose")[-1].speed_mm_s == 0.0
    assert g.published("robot/scan_status")[-1].state == "idle"


def test_a_change_the_scanner_does_not_apply_is_refused_not_acknowledged() -> None:
    g, scanner, op = scanner_graph()
    with pytest.raises(RequestRefused, match="'spacing_mm' is fixed at launch .*it may change: none"):
        set_param(g, op, spacing_mm=8)
    assert scanner.params.spacing_mm == 2.0 and g.published(PARAMS_TOPIC) == []


def test_a_probe_path_the_driver_refuses_ends_the_probe_and_the_next_one_runs() -> None:
    g, scanner, op = scanner_graph()
    # the robot's safety system stopped it while idle (a protective stop is latched until connect())
    scanner.driver.inject_fault(MotionStatus.PROTECTIVE_STOP, "protective stop (test)")
    first = probe(g, op, 30.0, 30.0)
    with pytest.raises(RequestRefused, match="the arm's driver refused the probe's path: .*protective stop"):
        first.result()
    g.advance(0.5)
    st = g.published("robot/scan_status")[-1]
    assert st.state == "idle" and "driver refused" in st.message and not scanner.is_shutdown
    assert g.published("robot/pose")[-1].speed_mm_s == 0.0
    scanner.driver.connect()  # the operator cleared the stop
    second = probe(g, op, 30.0, 30.0)
    assert g.published("robot/scan_status")[-1].state == "probing"
    t = 0.0
    while not second.done() and t < 30:
        g.publish("stiffness/sample", StiffnessSample(stamp_ns=g.clock.now_ns(), model="airfloat", x_mm=30.0,
                                                      y_mm=30.0, z_mm=5.0, value=30.0, unit="kPa", valid=True))
        g.advance(0.05)
        t += 0.05
    assert second.result().value == 30.0
    assert g.published("robot/scan_status")[-1].state == "idle"


def test_a_refusal_of_a_later_segment_of_the_probe_ends_it_too() -> None:
    """An indentation runs in segments (its hold splits it): the driver refusing the second one fails the probe."""
    g, scanner, op = scanner_graph()
    sent: list[int] = []
    move = scanner.driver.move_path

    def second_refused(points: Any) -> None:
        sent.append(len(points))
        if len(sent) == 2:
            raise ValueError("move_path: waypoint 0: speed_mm_s must be in (0, 5], got 10.0")
        move(points)

    scanner.driver.move_path = second_refused  # type: ignore[method-assign]
    fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(
        ProbeAt(x_mm=30.0, y_mm=30.0, mode="indent"))
    t = 0.0
    while not fut.done() and t < 30:
        g.advance(0.05)
        t += 0.05
    with pytest.raises(RequestRefused, match="driver refused the probe's path: move_path: waypoint 0"):
        fut.result()
    assert len(sent) == 2 and g.published("robot/scan_status")[-1].state == "idle" and not scanner.is_shutdown


def finished_scan() -> tuple[GraphHarness, RobotScanner, palpa.Node]:
    """A small raster scanned to the end: the scanner is ``done`` and lingers (2 s) before it exits 0."""
    g = GraphHarness()
    scanner = g.add(RobotScanner, {"region_mm": [10, 10, 20, 20], "spacing_mm": 5, "speed_mm_s": 20,
                                   "home_mm": [10, 10, 20], "watch_topic": "", "linger_s": 2.0}, name="scanner")
    op = g.add(palpa.Node, name="operator")
    for _ in range(2000):
        g.advance(0.05)
        if g.published("robot/scan_status")[-1].state == "done":
            break
    assert g.published("robot/scan_status")[-1].state == "done" and not scanner.is_shutdown
    return g, scanner, op


def test_a_finished_scan_refuses_a_probe_saying_why_and_exits_as_it_would_have() -> None:
    """A probe asked for during the linger was accepted, and the node exited mid-probe (the arm left on its way)."""
    g, scanner, op = finished_scan()
    before = scanner.driver.state().pose[:3]
    fut = probe(g, op, 15.0, 15.0)
    with pytest.raises(RequestRefused, match=r"the scanner has ended \(done\) and exits after linger_s: a probe "
                                             "would be cut off mid-path"):
        fut.result()
    g.advance(0.5)
    assert g.published("robot/scan_status")[-1].state == "done" and scanner.driver.state().pose[:3] == before
    g.advance(2.0)
    assert scanner.is_shutdown and scanner.exit_code == 0


def test_an_estop_while_done_is_acknowledged_and_latched() -> None:
    """It was ignored: the status stayed ``done`` and the node exited 0 as if nothing had been pressed."""
    g, scanner, op = finished_scan()
    stops: list[float] = []
    stop = scanner.driver.stop
    scanner.driver.stop = lambda decel: (stops.append(decel), stop(decel))[1]  # type: ignore[method-assign]
    g.advance(1.0)  # half the linger gone: the e-stop's exit code must replace the scan's on the first timer
    g.publish("robot/estop", EStop(stamp_ns=g.clock.now_ns(), engaged=True, reason="operator"))
    g.advance(0.05)
    st = g.published("robot/scan_status")[-1]
    assert st.state == "estop" and st.message == "e-stop: operator" and stops
    g.publish("robot/estop", EStop(stamp_ns=g.clock.now_ns(), engaged=False))
    g.advance(0.05)
    assert g.published("robot/scan_status")[-1].state == "estop"  # latched: a release does not undo it
    g.advance(3.0)
    assert scanner.is_shutdown and scanner.exit_code == 2
