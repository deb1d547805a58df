"""The scanner's timers fall on few distinct instants (a lockstep simulation pays a round of ticks and acks for each)
without its supervision getting rarer than every 10 ms."""

from __future__ import annotations

from typing import Any

import pytest

from messages import ProbeHeights
from nodes.scanner.robot_scanner import SUPERVISION_MAX_S, RobotScanner, supervision_period_s
from palpa.testing import NodeHarness

SMALL: dict[str, Any] = {"region_mm": [10, 10, 20, 20], "spacing_mm": 5, "speed_mm_s": 20, "home_mm": [10, 10, 20]}


def _instants(h: NodeHarness[RobotScanner], seconds: float) -> list[int]:
    """The distinct timer deadlines of the scanner over ``seconds`` of its clock, running each (probe data fed)."""
    end = h.clock.now_ns() + int(seconds * 1e9)
    seen = []
    while (due := h.node.next_timer_due_ns()) is not None and due <= end:
        seen.append(due)
        h.clock.set(due)
        h.publish("probe/heights", ProbeHeights(stamp_ns=due, seq=0, h_mm=(1, 1, 1, 2), raw=(0, 0, 0, 0),
                                                d_in_mm=1.0, tilt_rad=0.0))
        h.spin()
    return seen


def test_a_simulated_second_of_scanning_is_250_instants() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    _instants(h, 0.5)  # past the start: touching off, then scanning
    instants = _instants(h, 1.0)
    assert h.node.state in ("touching", "scanning")
    assert len(instants) == len(set(instants)) == 250  # the 250 Hz pose timer's: supervision shares them
    h.close()


@pytest.mark.parametrize("pose_rate_hz", [1000, 500, 300, 250, 200, 125, 100, 77, 60, 3])
def test_supervision_is_on_the_pose_grid_and_never_rarer_than_10_ms(pose_rate_hz: float) -> None:
    pose_ns = int(1.0 / pose_rate_hz * 1e9)
    supervise_ns = int(supervision_period_s(pose_rate_hz) * 1e9)
    assert supervise_ns <= SUPERVISION_MAX_S * 1e9 == 10_000_000
    if pose_ns <= supervise_ns:
        assert supervise_ns % pose_ns == 0 and supervise_ns + pose_ns > 10_000_000  # the most that fit


def test_stale_probe_data_stops_the_arm_within_the_watchdog_and_one_supervision_period() -> None:
    h = NodeHarness(RobotScanner, {**SMALL, "watchdog_s": 0.05, "touchoff": "off"})
    _instants(h, 0.3)
    assert h.node.state == "scanning"
    last = h.clock.now_ns()
    while h.node.state == "scanning":
        due = h.node.next_timer_due_ns()
        assert due is not None
        h.clock.set(due)
        h.spin()
    assert h.node.state == "fault"
    assert (h.clock.now_ns() - last) / 1e9 <= 0.05 + supervision_period_s(250.0) + 1e-9
    h.close()
