"""Alicat pressure controller: the serial driver against the pty emulator (the codec: test_devices_alicat.py)."""

from __future__ import annotations

import contextlib
import math
import signal
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from emulators.alicat import AlicatEmulator
from nodes.drivers.pressure import (
    FLAG_CLAMPED,
    FLAG_OVER_MAX,
    AlicatPressureDriver,
    PressureCommandError,
    PressureDriver,
    PressureNotConnectedError,
    PressureReading,
    PressureTimeoutError,
)
from tests.procs import ProcessGroup, wait_until

pytestmark = [pytest.mark.system, pytest.mark.timeout(30)]

REPO = Path(__file__).resolve().parents[1]
MAX_KPA = 40.0


class FakeClock:
    """Monotonic seconds that only move when the test says so (drives the emulator's plant)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt_s: float) -> None:
        self.t += dt_s



@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def make_emu(clock: FakeClock, stack: contextlib.ExitStack) -> Callable[..., AlicatEmulator]:
    def make(**kw: object) -> AlicatEmulator:
        kw.setdefault("clock", clock)
        kw.setdefault("tau_s", 0.02)
        kw.setdefault("rate_limit_kpa_s", 1000.0)
        return stack.enter_context(AlicatEmulator(**kw))  # type: ignore[arg-type]

    return make


@pytest.fixture
def make_driver(stack: contextlib.ExitStack) -> Callable[..., AlicatPressureDriver]:
    def make(port: str, unit_id: str = "A", **kw: object) -> AlicatPressureDriver:
        kw.setdefault("backoff_s", (0.01, 0.05))
        kw.setdefault("timeout_s", 1.0)  # generous: the machine is shared; muted-reply tests pass their own
        return stack.enter_context(AlicatPressureDriver(port, unit_id, MAX_KPA, **kw))  # type: ignore[arg-type]

    return make


def poll(drv: AlicatPressureDriver) -> PressureReading:
    reading = drv.read(1.0)
    assert reading is not None, f"no reading: {drv.status()}"
    return reading


# --- driver against the emulator -------------------------------------------------------


def test_poll_and_setpoint_track_the_plant(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver], clock: FakeClock) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    assert isinstance(drv, PressureDriver)
    first = poll(drv)
    assert (first.setpoint_kpa, first.measured_kpa, first.flags) == (0.0, 0.0, frozenset())
    echo = drv.set_setpoint(30.0)
    assert echo.setpoint_kpa == 30.0 and echo.flags == frozenset()
    clock.advance(0.01)  # 10 ms at 1000 kPa/s: still on the ramp
    assert poll(drv).measured_kpa == pytest.approx(10.0, abs=0.5)
    clock.advance(1.0)
    r = poll(drv)
    assert r.measured_kpa == pytest.approx(30.0, abs=0.01) and r.setpoint_kpa == 30.0
    assert drv.status().commanded_kpa == 30.0 and drv.status().connected
    assert emu.commands[:2] == ["A", "AS30.000"]


def test_hold_freezes_and_vent_releases(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver], clock: FakeClock) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    drv.set_setpoint(30.0)
    clock.advance(1.0)
    held = drv.hold()
    assert "HLD" in held.flags
    drv.set_setpoint(10.0)
    clock.advance(1.0)
    r = poll(drv)
    assert "HLD" in r.flags and r.setpoint_kpa == 10.0 and r.measured_kpa == pytest.approx(30.0, abs=0.01)
    vented = drv.vent()
    assert "HLD" not in vented.flags and vented.setpoint_kpa == 0.0
    clock.advance(1.0)
    assert poll(drv).measured_kpa == pytest.approx(0.0, abs=0.01)
    assert emu.commands[-3:] == ["AC", "AS0.000", "A"]


def test_question_mark_reply_is_an_error_not_a_crash(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    emu.fail_next()
    with pytest.raises(PressureCommandError, match="'\\?'"):
        drv.hold()
    emu.fail_next()
    assert drv.read(1.0) is None
    assert drv.status().counters.unknown == 2
    assert "HLD" not in poll(drv).flags  # the refused hold was not executed
    assert drv.identify().startswith("10v")


def test_timeouts_are_counted_and_recovered(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port, timeout_s=0.1)
    emu.mute_next()
    assert drv.read(0.1) is None
    emu.mute_next()
    with pytest.raises(PressureTimeoutError, match="no reply"):
        drv.set_setpoint(5.0)
    assert drv.status().counters.timeouts == 2
    assert poll(drv).setpoint_kpa == 0.0  # the lost set-point never reached the device
    assert drv.status().connected


def test_other_unit_id_is_ignored_on_the_bus(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu(unit_id="B")
    drv_a = make_driver(emu.port, "A", timeout_s=0.05)
    assert drv_a.read(0.05) is None
    assert emu.commands == []
    drv_a.close()
    drv_b = make_driver(emu.port, "B")
    assert poll(drv_b).setpoint_kpa == 0.0


def test_unplug_is_reported_and_driver_reconnects(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    drv.set_setpoint(20.0)
    emu.unplug()
    assert drv.read(0.1) is None
    st = drv.status()
    assert not st.connected and "lost" in (st.last_error or "")
    with pytest.raises(PressureNotConnectedError, match=emu.port):
        drv.set_setpoint(5.0)
    emu.replug()
    wait_until(lambda: drv.read(0.2) is not None, what="reconnect after replug")
    st = drv.status()
    assert st.connected and st.counters.reconnects == 1
    assert poll(drv).setpoint_kpa == 20.0  # the controller kept its set-point


def test_missing_device_raises_or_waits(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu()
    emu.unplug()
    with pytest.raises(PressureNotConnectedError, match="plugged in"):
        AlicatPressureDriver(emu.port, "A", MAX_KPA).open()
    drv = make_driver(emu.port, require_device=False)
    assert drv.read(0.05) is None and not drv.status().connected
    emu.replug()
    wait_until(lambda: drv.read(0.2) is not None, what="device to appear")
    assert drv.status().counters.reconnects == 0  # first connection, not a re-connection


def test_hard_cap_is_enforced_in_the_driver(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver]) -> None:
    emu = make_emu(full_scale_kpa=100.0)
    drv = make_driver(emu.port)
    r = drv.set_setpoint(80.0)
    assert FLAG_CLAMPED in r.flags and r.setpoint_kpa == MAX_KPA
    assert emu.setpoint_kpa == MAX_KPA  # the device never saw 80
    st = drv.status()
    assert st.counters.clamped == 1 and "hard maximum" in (st.last_error or "") and st.commanded_kpa == MAX_KPA
    assert FLAG_CLAMPED in drv.set_setpoint(-5.0).flags and emu.setpoint_kpa == 0.0
    assert FLAG_CLAMPED not in drv.set_setpoint(MAX_KPA).flags
    sent_before = len(emu.commands)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError):
            drv.set_setpoint(bad)
    assert len(emu.commands) == sent_before


def test_stuck_valve_shows_in_readback(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver], clock: FakeClock) -> None:
    emu = make_emu(full_scale_kpa=100.0)
    drv = make_driver(emu.port)
    emu.stick_valve("frozen")
    drv.set_setpoint(30.0)
    clock.advance(1.0)
    r = poll(drv)
    assert r.setpoint_kpa == 30.0 and r.measured_kpa == 0.0
    emu.stick_valve("open")  # fails towards the supply pressure
    clock.advance(1.0)
    r = poll(drv)
    assert r.measured_kpa == pytest.approx(100.0) and FLAG_OVER_MAX in r.flags


def test_device_units_are_converted(make_emu: Callable[..., AlicatEmulator], make_driver: Callable[..., AlicatPressureDriver], clock: FakeClock) -> None:
    emu = make_emu(device_unit="psi")
    drv = make_driver(emu.port, device_unit="psi")
    assert drv.set_setpoint(30.0).setpoint_kpa == pytest.approx(30.0, abs=0.01)  # 2 decimals of psi on the wire
    assert emu.setpoint_kpa == pytest.approx(30.0, abs=1e-3)
    clock.advance(1.0)
    assert poll(drv).measured_kpa == pytest.approx(30.0, abs=0.01)


def test_cli_prints_port_and_stops_on_sigterm(make_driver: Callable[..., AlicatPressureDriver],
                                               procs: ProcessGroup) -> None:
    proc = procs.start([sys.executable, "-m", "emulators.alicat"], cwd=str(REPO))
    port = proc.first_line(15.0)
    drv = make_driver(port)
    assert drv.set_setpoint(12.5).setpoint_kpa == 12.5
    proc.signal(signal.SIGTERM)
    assert proc.wait(10.0) == 0
    assert not Path(port).exists()
