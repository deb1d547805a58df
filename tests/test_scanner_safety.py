"""The scanner's safety limits hold while it runs (issue 39): no run-time change widens the workspace box or a cap,
a change the scanner does not apply is refused rather than acknowledged, and a probe whose path the arm's driver
refuses ends the probe (idle again, the reason said) instead of leaving the scanner in ``probing``."""

from __future__ import annotations

from typing import Any

import pytest

import palpa
from messages import ProbeAt, ProbeResult, StiffnessSample
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
