"""The scanner's state machine (nodes/scanner/states.py): the tests read its one table of transitions, and the
scanner changes state only through it (issue 38). Also the changes the table made explicit: an abort stops a
touch-off, and a scan path the arm's driver refuses ends the scan as a fault with the driver's reason (issue 39's
leftover: it raised in the timer and left the scanner ``scanning``)."""

from __future__ import annotations

import ast
import typing
from collections import deque
from pathlib import Path
from typing import Any

import pytest

import palpa
from messages import ProbeHeights, Trigger, TriggerResult
from messages.robot import ScanState
from nodes.drivers.robot import MotionStatus
from nodes.scanner.robot_scanner import RobotScanner
from nodes.scanner.states import (
    FINAL,
    MOVING,
    PAUSED,
    TRANSITIONS,
    Event,
    IllegalTransition,
    ScanStateMachine,
    State,
)
from palpa.testing import NodeHarness

ROOT = Path(__file__).resolve().parent.parent
SMALL: dict[str, Any] = {"region_mm": [10, 10, 20, 20], "spacing_mm": 5, "speed_mm_s": 20, "home_mm": [10, 10, 20],
                         "watch_topic": ""}


def reachable(start: State) -> set[State]:
    seen, todo = {start}, deque([start])
    while todo:
        a = todo.popleft()
        for frm, _, to in TRANSITIONS:
            if frm is a and to not in seen:
                seen.add(to)
                todo.append(to)
    return seen


def test_the_table_is_a_function_of_state_and_event() -> None:
    """A (from-state, event) pair twice would silently keep one of them."""
    pairs = [(a, e) for a, e, _ in TRANSITIONS]
    assert len(pairs) == len(set(pairs))


def test_every_state_is_reachable_from_planning_and_every_event_is_used() -> None:
    assert reachable(State.PLANNING) == set(State)
    assert {e for _, e, _ in TRANSITIONS} == set(Event)


def test_every_state_that_is_not_final_can_end_idle_done_or_in_a_fault() -> None:
    ends = {State.IDLE, State.DONE, State.FAULT}
    assert {s: sorted(x.name for x in reachable(s)) for s in State
            if s not in FINAL and not (reachable(s) - {s}) & ends} == {}


def test_estop_and_abort_stop_the_arm_from_every_state_it_is_under_way_in() -> None:
    nxt = {(a, e): b for a, e, b in TRANSITIONS}
    under_way = MOVING | PAUSED | {State.WAITING}
    assert {s for s in set(State) - {State.PLANNING, State.ESTOP} if nxt.get((s, Event.ESTOP)) is not
            State.ESTOP} == set()  # always acknowledged (planning is setup: no event happens before it is over)
    assert {s: nxt.get((s, Event.ABORT)) for s in under_way
            if nxt.get((s, Event.ABORT)) not in (State.IDLE, State.STOPPED)} == {}
    # nothing leaves e-stop (latched), and no final state starts the arm (the node exits after its linger)
    assert not [t for t in TRANSITIONS if t[0] is State.ESTOP]
    assert {(a, b) for a, _, b in TRANSITIONS if a in FINAL and b is not State.ESTOP} == set()


def test_the_published_names_are_the_messages() -> None:
    wire = set(typing.get_args(ScanState))
    assert {s.wire for s in State} <= wire
    assert wire - {s.wire for s in State} == {"approach"}  # declared in messages.robot, never used by the scanner
    assert {s.wire for s in PAUSED} == {"paused"}


def test_a_change_not_in_the_table_raises_and_changes_nothing() -> None:
    m = ScanStateMachine(State.IDLE)
    assert not m.can(Event.RESUME)
    with pytest.raises(IllegalTransition, match="cannot 'go on .*' while idle"):
        m.fire(Event.RESUME)
    assert m.state is State.IDLE and m.fire(Event.PROBE) is State.PROBING


def test_the_scanner_changes_state_only_through_the_table() -> None:
    """No module of nodes/scanner but states.py assigns a ``state`` attribute: the ~50 ``set_state`` sites are
    events now. And a change the table lacks raises in the scanner too."""
    assigned = []
    for path in sorted((ROOT / "nodes" / "scanner").glob("*.py")):
        if path.name == "states.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else []
            assigned += [f"{path.name}:{node.lineno}" for t in targets
                         if isinstance(t, ast.Attribute) and t.attr == "state"]
    assert assigned == []
    h = NodeHarness(RobotScanner, {**SMALL, "autostart": False})
    assert h.node.state == "idle"
    with pytest.raises(IllegalTransition):
        h.node.change(Event.COMPLETE)
    assert h.node.state == "idle"


def speed(h: NodeHarness[RobotScanner]) -> float:
    return float(h.published("robot/pose")[-1].speed_mm_s)


def test_a_scan_path_the_driver_refuses_ends_the_scan_as_a_fault_with_the_drivers_reason() -> None:
    """The first segment: the robot's safety system stopped it before the scan (latched until connect())."""
    h = NodeHarness(RobotScanner, SMALL)
    h.node.driver.inject_fault(MotionStatus.PROTECTIVE_STOP, "protective stop (test)")  # type: ignore[attr-defined]
    h.advance(0.1)
    st = h.published("robot/scan_status")[-1]
    assert st.state == "fault" and st.message.startswith("the arm's driver refused the scan's path: ") and \
        "protective stop (test)" in st.message, st
    assert speed(h) == 0.0
    h.advance(1.0)
    assert h.node.is_shutdown and h.node.exit_code == 1


def test_a_refusal_of_a_later_segment_of_the_scan_ends_it_too() -> None:
    """An indentation runs in segments (its holds split it): the driver refusing the second one stops the arm
    where it is and ends the scan as a fault naming the driver's reason."""
    h = NodeHarness(RobotScanner, {**SMALL, "mode": "indent", "spacing_mm": 10, "contact_z_mm": 10.0,
                                   "indent_depth_mm": 2.0, "hold_s": 0.1})
    sent: list[int] = []
    move, stops = h.node.driver.move_path, h.node.driver.stop
    stopped: list[float] = []

    def second_refused(points: Any) -> None:
        sent.append(len(points))
        if len(sent) == 2:
            raise ValueError("move_path: waypoint 0: speed_mm_s must be in (0, 5], got 10.0")
        move(points)

    def stop(decel: float) -> None:
        stopped.append(decel)
        stops(decel)

    h.node.driver.move_path = second_refused  # type: ignore[method-assign]
    h.node.driver.stop = stop  # type: ignore[method-assign]
    for _ in range(3000):
        h.advance(0.01)
        if h.node.state != "scanning" and len(sent) >= 2:
            break
    st = h.published("robot/scan_status")[-1]
    assert len(sent) == 2 and st.state == "fault" and "driver refused the scan's path: move_path: waypoint 0" in \
        st.message, st
    assert stopped, "the arm was not stopped"
    h.advance(1.0)
    assert h.node.exit_code == 1


def test_an_abort_during_the_touch_off_stops_the_arm_and_ends_the_scan(tmp_path: Path) -> None:
    """scanner/abort was refused while touching ("nothing to abort"): the table has every moving state stop."""
    geometry = tmp_path / "geometry.yaml"
    geometry.write_text("thickness_mm: 6.0\nfootprint_mm: [0, 0, 40, 40]\n")
    h = NodeHarness(RobotScanner, {"geometry": str(geometry), "touchoff": "heights", "spacing_mm": 8,
                                   "speed_mm_s": 20, "home_mm": [5, 5, 30], "watchdog_s": 0.5})
    abort = h.add(palpa.Node, name="operator").client("scanner/abort", Trigger, TriggerResult)
    for _ in range(2000):
        h.publish("probe/heights", ProbeHeights(stamp_ns=h.clock.now_ns(), seq=0, h_mm=(10.0, 10.0, 10.0, 10.0),
                                                raw=(0, 0, 0, 0), d_in_mm=0.0, tilt_rad=0.0))  # nothing touched
        h.advance(0.004)
        if h.node.state == "touching" and speed(h) > 1.0:
            break
    assert h.node.state == "touching" and speed(h) > 1.0
    fut = abort.call_async(Trigger())
    h.spin()
    assert fut.result().state == "stopped" and fut.result().message == "aborted (touching)"
    h.advance(0.3)
    assert speed(h) == 0.0 and h.published("robot/scan_status")[-1].state == "stopped"
    h.advance(1.0)
    assert h.node.exit_code == 2
