"""The UR emulator's controller stepped by a given clock (emulators.ur.stepper), in process: its cycles follow that
clock's time, not the wall's, so an in-process graph and the emulated arm share one simulated time."""

from __future__ import annotations

import time

import pytest

from emulators.ur.controller import UrController
from emulators.ur.stepper import TICK_NS, ControllerClock
from models.arm import ArmTarget
from palpa.timing.clock import MockClock


def test_the_controller_runs_one_cycle_per_tick_of_its_clock_whatever_the_wall_does(
        monkeypatch: pytest.MonkeyPatch) -> None:
    clock = MockClock()
    ctl = UrController()
    stepper = ControllerClock(ctl, clock.now_ns)
    mono_ns = time.monotonic_ns
    monkeypatch.setattr(time, "monotonic_ns", lambda: mono_ns() + 3600 * 10**9)  # a starved process wakes up
    assert stepper.step() == 0 and ctl.ticks == 0
    clock.advance(0.1)
    assert stepper.step() == 50 and ctl.ticks == 50
    assert stepper.step() == 0 and stepper.next_due_ns() == clock.now_ns() + TICK_NS
    clock.advance(0.0015)
    assert stepper.step() == 0  # not a whole cycle yet
    clock.advance(0.0005)
    assert stepper.step() == 1 and ctl.ticks == 51


def test_a_motion_moves_the_arm_by_the_clock_and_holds_it_at_hold_at() -> None:
    clock = MockClock()
    ctl = UrController()
    stepper = ControllerClock(ctl, clock.now_ns)
    x0 = ctl.arm.pose[0]
    with ctl.lock:
        ctl.start_motion([ArmTarget(pose=(x0 + 50.0, *ctl.arm.pose[1:]), speed_mm_s=100.0, accel_mm_s2=1000.0)])
    for _ in range(10):
        clock.advance(0.01)
        stepper.step(hold_at=25)
    assert ctl.ticks == 50 and ctl.arm_steps == 25  # held once it had moved 25 cycles: the rest ran held
    moved = ctl.arm.pose[0] - x0
    assert moved > 0
    clock.advance(0.01)
    stepper.step()
    assert ctl.arm_steps == 30 and ctl.arm.pose[0] - x0 > moved


def test_a_controller_that_falls_behind_skips_cycles_and_says_so() -> None:
    clock = MockClock()
    ctl = UrController()
    stepper = ControllerClock(ctl, clock.now_ns, max_catchup=50)
    clock.advance(1.0)
    assert stepper.step() == 50 and ctl.ticks == 50
    assert any("skipping 450 ticks" in m for m in ctl.messages)
    clock.advance(0.01)
    assert stepper.step() == 5  # on from the clock's now: the skipped cycles are not run later


def test_cycles_run_ahead_of_the_clock_count_as_its_next_ones() -> None:
    """A blocking client call runs the controller until it answers (emulators.ur.local): those cycles are not run
    again when the clock reaches them."""
    clock = MockClock()
    ctl = UrController()
    stepper = ControllerClock(ctl, clock.now_ns)
    assert stepper.run_ahead(lambda: ctl.ticks >= 7, 100) == 7 and ctl.ticks == 7
    clock.advance(0.01)  # 5 cycles: already run
    assert stepper.step() == 0 and ctl.ticks == 7
    clock.advance(0.006)  # 8 cycles in all
    assert stepper.step() == 1 and ctl.ticks == 8
    assert stepper.run_ahead(lambda: False, 3) is None and ctl.ticks == 11  # never answered: gives up
