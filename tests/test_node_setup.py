"""A node's lifecycle edges: resources registered with ``Node.closing`` are closed when ``setup()`` raises and at
shutdown (the refused-plan case of the robot scanner, with the sim driver and through the UR emulator; a setup
refused after the serial, camera and regulator drivers opened), and ``Timer.cancel``."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

import palpa
from emulators.alicat import AlicatEmulator
from emulators.fibre_daq import FibreDaqEmulator, source_from_heights
from models.fibre_calibration import load_calibration
from nodes.drivers.robot import PathPoint, RobotDriver, RobotDriverError
from nodes.probe.camera_tracker import CameraTracker
from nodes.probe.fibre_reader import FibreReader
from nodes.probe.pressure_controller import PressureController
from nodes.scanner.robot_scanner import RobotScanner
from palpa.testing import MemoryBus, NodeHarness
from palpa.timing.clock import MockClock
from tests.procs import ur_emulator

SMALL: dict[str, Any] = {"region_mm": [10, 10, 20, 20], "spacing_mm": 5, "speed_mm_s": 20, "home_mm": [10, 10, 20]}
OUT_OF_THE_BOX: dict[str, Any] = {**SMALL, "region_mm": [10, 10, 80, 20]}  # x = 80 > the workspace's 70
A_MOVE = [PathPoint(10.0, 12.0, 20.0, 10.0, 100.0)]


class _Closable:
    def __init__(self, log: list[str], name: str, fail: bool = False) -> None:
        self.log, self.name, self.fail = log, name, fail

    def close(self) -> None:
        self.log.append(self.name)
        if self.fail:
            raise OSError(f"{self.name} would not close")


class _KeepsDriver(RobotScanner):
    """The real scanner with its real sim driver, remembered so the test can look at it after setup() raised."""

    made: list[RobotDriver] = []

    def _make_driver(self) -> RobotDriver:
        driver = super()._make_driver()
        _KeepsDriver.made.append(driver)
        return driver


def test_refused_plan_closes_the_sim_driver_and_the_transport() -> None:
    _KeepsDriver.made.clear()
    transport = MemoryBus().transport()
    with pytest.raises(palpa.ParamError, match="refusing the specimen before any motion"):
        _KeepsDriver(params=OUT_OF_THE_BOX, transport=transport, clock=MockClock(), heartbeat_s=0)
    (driver,) = _KeepsDriver.made
    with pytest.raises(RobotDriverError, match="not connected"):
        driver.move_path(A_MOVE)  # setup() had connected it; the refusal closed it
    assert transport.closed


def test_an_accepted_plan_keeps_the_driver_until_the_node_closes() -> None:
    _KeepsDriver.made.clear()
    h = NodeHarness(_KeepsDriver, SMALL)
    (driver,) = _KeepsDriver.made
    driver.stop(1000.0)  # connected: stop() acts, move_path() would be accepted
    h.close()
    with pytest.raises(RobotDriverError, match="not connected"):
        driver.move_path(A_MOVE)


@pytest.mark.xdist_group("ur-emulator")  # real-time emulator: one at a time (make test)
@pytest.mark.slow
@pytest.mark.system
def test_refused_plan_disconnects_from_the_ur_emulator() -> None:
    pytest.importorskip("rtde_control")
    with ur_emulator([]) as emu:
        params = {**OUT_OF_THE_BOX, "driver": "ur_rtde", "robot_host": emu.host}
        # refused after the driver connected: the region does not fit the box (the specimen check comes first)
        with pytest.raises(palpa.ParamError, match="refusing the specimen before any motion"):
            RobotScanner(params=params, transport=MemoryBus().transport(), clock=MockClock(), heartbeat_s=0)
        assert emu.command("program")["source"]  # the driver did connect and upload its control script
        emu.wait_state(lambda st: st["clients"] == 0, timeout_s=10.0)


class _RefusesAfterOpening(palpa.Node):
    """Mixed in before a driver node: its setup() opens the driver, then this refuses to go on (as a plan check
    would); the driver is kept for the test in ``made``."""

    made: list[Any] = []

    def setup(self) -> None:
        super().setup()
        _RefusesAfterOpening.made.append(getattr(self, "driver"))  # noqa: B009 - each driver node has its own
        raise palpa.ParamError("refused after opening the driver")


class _RefusingFibre(_RefusesAfterOpening, FibreReader):
    pass


class _RefusingRegulator(_RefusesAfterOpening, PressureController):
    pass


class _RefusingCamera(_RefusesAfterOpening, CameraTracker):
    pass


def _refused(cls: type[palpa.Node], params: dict[str, Any]) -> Any:
    _RefusesAfterOpening.made.clear()
    transport = MemoryBus().transport()
    with pytest.raises(palpa.ParamError, match="refused after opening the driver"):
        cls(params=params, transport=transport, clock=MockClock(), heartbeat_s=0)
    assert transport.closed
    (driver,) = _RefusesAfterOpening.made
    return driver


def _threads_named(name: str) -> list[str]:
    return [t.name for t in threading.enumerate() if t.name == name and t.is_alive()]


@pytest.mark.system
def test_a_refused_setup_closes_the_serial_fibre_driver() -> None:
    cal = "tests/data/fibre_calibration.yaml"
    with FibreDaqEmulator(source_from_heights(load_calibration(cal), lambda t: (1.5, 1.5, 1.5, 3.5))) as emu:
        driver = _refused(_RefusingFibre, {"driver": "serial", "port": emu.port, "calibration": cal})
        assert not driver.status().connected  # connected at open(), then closed by the refusal
        assert _threads_named(f"fibre:{emu.port}") == []  # its acquisition thread is gone too


@pytest.mark.system
def test_a_refused_setup_closes_the_alicat_regulator_port() -> None:
    with AlicatEmulator() as emu:
        driver = _refused(_RefusingRegulator, {"driver": "alicat", "port": emu.port, "max_kpa": 30.0})
        assert not driver.status().connected


def test_a_refused_setup_stops_the_opencv_capture(tmp_path: Path) -> None:
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"f_{i:02d}.png"), np.zeros((48, 64, 3), np.uint8))
    device = str(tmp_path / "f_%02d.png")
    driver = _refused(_RefusingCamera, {"driver": "opencv", "device": device, "pacing": "every"})
    assert driver.info().kind == "sequence"
    assert _threads_named(f"camera {device}") == []  # the capture thread (waiting for a reader) was stopped


def test_closing_releases_in_reverse_order_at_shutdown_even_if_one_fails() -> None:
    closed: list[str] = []

    class Holder(palpa.Node):
        def setup(self) -> None:
            self.first = self.closing(_Closable(closed, "first"))
            self.closing(_Closable(closed, "second", fail=True))

        def on_shutdown(self) -> None:
            closed.append("on_shutdown")

    h = NodeHarness(Holder)
    assert h.node.first.name == "first" and closed == []
    h.close()
    assert closed == ["on_shutdown", "second", "first"]


def test_setup_error_goes_up_after_closing_what_was_registered() -> None:
    closed: list[str] = []
    transport = MemoryBus().transport()

    class Fails(palpa.Node):
        def setup(self) -> None:
            self.closing(_Closable(closed, "port"))
            raise RuntimeError("no such device")

        def on_shutdown(self) -> None:
            closed.append("on_shutdown")  # setup never finished: nothing to shut down but the resources

    with pytest.raises(RuntimeError, match="no such device"):
        Fails(transport=transport, clock=MockClock(), heartbeat_s=0)
    assert closed == ["port"] and transport.closed


def test_cancelled_timer_never_fires_again_and_others_keep_running() -> None:
    class Ticker(palpa.Node):
        def setup(self) -> None:
            self.ticks: list[str] = []
            self.a = self.timer(0.1, lambda: self.ticks.append("a"))
            self.b = self.timer(0.1, lambda: self.ticks.append("b"))

    h = NodeHarness(Ticker)
    h.advance(0.25)
    assert h.node.ticks.count("a") == 2 and h.node.ticks.count("b") == 2
    h.node.a.cancel()
    h.advance(0.5)
    assert h.node.ticks.count("a") == 2 and h.node.ticks.count("b") == 7
    assert h.node.next_timer_due_ns() == h.node.b.due_ns


def test_a_timer_cancelled_from_its_own_callback_stops() -> None:
    class Countdown(palpa.Node):
        def setup(self) -> None:
            self.left = 3
            self.t = self.timer(0.1, self.tick)

        def tick(self) -> None:
            self.left -= 1
            if self.left == 0:
                self.t.cancel()

    h = NodeHarness(Countdown)
    h.advance(1.0)
    assert h.node.left == 0 and h.node.next_timer_due_ns() is None
