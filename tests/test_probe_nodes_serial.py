"""The air-float nodes with their REAL drivers, against the device emulators on ptys: the node publishes what
the device streams, says when it is down, recovers on replug; the regulator node caps and faults over serial."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from emulators.alicat import AlicatEmulator
from emulators.fibre_daq import FibreDaqEmulator, source_from_heights
from messages import PressureCommand
from models.fibre_calibration import load_calibration
from nodes.probe.fibre_reader import FibreReader
from nodes.probe.pressure_controller import PressureController
from palpa.testing import NodeHarness
from tests.procs import wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

CAL = "tests/data/fibre_calibration.yaml"


def last(h: NodeHarness, topic: str):  # type: ignore[no-untyped-def]
    msgs = h.published(topic)
    return msgs[-1] if msgs else None


def run_until(h: NodeHarness, cond: Callable[[], bool], timeout: float, what: str) -> None:
    """Drive the node's timers on the real clock (the drivers have real threads) until ``cond``."""
    def step() -> None:
        h.advance(0.01)
        time.sleep(0.005)  # let the driver's reader thread run; the wait itself is bounded by wait_until

    wait_until(cond, timeout, what, step=step)


def test_fibre_reader_serial_streams_and_recovers_from_unplug() -> None:
    cal = load_calibration(CAL)
    heights = (1.5, 1.5, 1.5, 3.5)
    with FibreDaqEmulator(source_from_heights(cal, lambda t: heights), rate_hz=200) as emu:
        h = NodeHarness(FibreReader, {"driver": "serial", "port": emu.port, "calibration": CAL, "rate_hz": 200})
        try:
            run_until(h, lambda: len(h.published("probe/heights")) >= 20, 10, "first samples")
            sample = h.published("probe/heights")[-1]
            assert all(abs(a - b) < 0.05 for a, b in zip(sample.h_mm, heights, strict=True))
            assert abs(sample.d_in_mm - 2.0) < 0.1  # eqs. 1-3 on a level plane: h4 - h_sps
            emu.inject_garbage()
            emu.drop_next(3)
            n = len(h.published("probe/heights"))
            run_until(h, lambda: len(h.published("probe/heights")) > n + 20, 10, "samples after garbage")
            emu.unplug()
            run_until(h, lambda: not last(h, "probe/status").connected, 10, "status down")
            assert h.published("probe/status")[-1].state == "down"
            emu.replug()
            n = len(h.published("probe/heights"))
            run_until(h, lambda: len(h.published("probe/heights")) > n + 20, 15, "samples after replug")
            run_until(h, lambda: h.published("probe/status")[-1].connected, 10, "status up")
            counters = h.published("probe/status")[-1].counters
            assert counters["reconnects"] >= 1 and counters["dropped"] >= 3 and counters["resyncs"] >= 1
        finally:
            h.close()


def test_pressure_controller_over_alicat_caps_and_detects_unplug() -> None:
    with AlicatEmulator(tau_s=0.02, rate_limit_kpa_s=500.0) as emu:
        h = NodeHarness(PressureController, {"driver": "alicat", "port": emu.port, "max_kpa": 30.0,
                                             "startup": "hold", "setpoint_kpa": 20.0, "lost_timeout_s": 0.3})
        try:
            run_until(h, lambda: (s := last(h, "pressure/state")) is not None and abs(s.measured_kpa - 20) < 1, 10, "20 kPa")
            h.publish("pressure/command", PressureCommand(mode="hold", setpoint_kpa=95.0))
            run_until(h, lambda: abs(last(h, "pressure/state").measured_kpa - 30) < 1, 10, "capped")
            states = h.published("pressure/state")
            assert max(s.measured_kpa for s in states) < 30.5 and "clamped" in states[-1].faults
            emu.unplug()
            run_until(h, lambda: "device_lost" in h.published("pressure/state")[-1].faults, 10, "device_lost")
        finally:
            h.close()
