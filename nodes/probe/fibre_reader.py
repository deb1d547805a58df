"""Fibre-optic reader node: the air-float probe's four displacement sensors -> ``probe/heights``.

``driver: serial`` reads the DAQ line protocol (docs/devices.md) through pyserial; ``driver: sim`` is the simulated
probe (nodes/drivers/fibre_sim.py): heights from the world over the phantom, the robot pose (``robot/pose``) and
the regulator's read-back (``pressure/state``), through the device's drawn errors. Both publish the same topics:
``probe/heights`` (h1..h4 mm, raw values, eqs. 1-3 depth and tilt) and ``probe/status``; the sim driver also
publishes its error draw once, latched, on ``sim/truth/fibre`` (JSON text) so that the recording keeps it.
The service ``probe/tare`` (:class:`Trigger`) zeroes the sensors at the current pose (the device's ``$ZERO``).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Literal

import numpy as np

import palpa
from messages import (
    DeviceStatus,
    PressureState,
    ProbeHeights,
    RobotPose,
    Text,
    Trigger,
    TriggerResult,
)
from models.airfloat import (
    DEFAULT_INDENTER_RADIUS_MM,
    DEFAULT_SPS_RADIUS_MM,
    indentation_from_heights,
)
from models.airfloat_device import ProbeErrors
from nodes.common import phantom_from_param
from nodes.drivers.fibre import FibreDriver, FibreError, FibreSample
from nodes.drivers.fibre_serial import SerialFibreDriver
from nodes.drivers.fibre_sim import SimFibreDriver
from palpa.node.service import RequestRefused

__all__ = ["FibreReader"]


class FibreReader(palpa.Node):
    """Polls a fibre driver and publishes every sample it gives."""

    class Params(palpa.Params):
        driver: Literal["sim", "serial"] = "sim"
        rate_hz: palpa.Positive = 500.0
        """Sensor sample rate asked of the device (or simulated)."""
        poll_hz: palpa.Positive = 50.0
        """How often the node drains the driver's queue."""
        port: str = "/dev/ttyACM0"
        baudrate: palpa.PositiveInt = 115200
        calibration: palpa.InputPath = ""
        """Calibration YAML of the four channels (serial driver)."""
        phantom: palpa.InputPath = ""
        """Phantom YAML (sim driver)."""
        noise_mm: float = -1.0
        """Sim sensor noise σ (mm); negative: the phantom file's value."""
        sim_errors: Literal["realistic", "ideal"] = "realistic"
        """Sim device errors drawn from ``device_seed`` (docs/airfloat-sim.md); ``ideal``: a perfect device, unit tests
        only."""
        device_seed: int = 0
        """Which simulated probe (its error draw); calibrate with the same one (``tools.calibrate_airfloat``)."""
        sps_radius_mm: palpa.Positive = DEFAULT_SPS_RADIUS_MM
        indenter_radius_mm: palpa.Positive = DEFAULT_INDENTER_RADIUS_MM
        stroke_mm: palpa.Positive = 10.0
        seed: int = 0

    params: Params

    def setup(self) -> None:
        p = self.params
        self.heights = self.publisher("probe/heights", ProbeHeights)
        self.status_pub = self.publisher("probe/status", DeviceStatus, latched=True)
        self.driver: FibreDriver
        if p.driver == "sim":
            phantom = phantom_from_param(p.phantom, self.name)
            noise = phantom.noise.displacement_mm if p.noise_mm < 0 else p.noise_mm
            errors = (ProbeErrors.draw(p.device_seed, noise_mm=noise) if p.sim_errors == "realistic"
                      else dataclasses.replace(ProbeErrors.ideal(), noise_mm=noise))
            sim = SimFibreDriver(
                phantom, self.clock.now_ns, errors=errors, rate_hz=p.rate_hz, sps_radius_mm=p.sps_radius_mm,
                indenter_radius_mm=p.indenter_radius_mm, stroke_mm=p.stroke_mm, seed=p.seed,
            )
            self.publisher("sim/truth/fibre", Text, latched=True).publish(Text(
                stamp_ns=self.clock.now_ns(), text=json.dumps({"driver": "sim", "errors": errors.as_dict()})))
            self.log.info("sim probe errors (device_seed %d): %s", p.device_seed, errors.as_dict())
            self.subscribe("robot/pose", self.on_pose)
            self.subscribe("pressure/state", self.on_pressure)
            self.driver = self.closing(sim)
            self._sim: SimFibreDriver | None = sim
        else:
            # closed by the node whatever happens next, a failing setup() included
            self.driver = self.closing(SerialFibreDriver(p.port, p.baudrate, p.calibration, require_device=False,
                                                         clock=self.clock.now_ns))
            self._sim = None
        self.driver.open()
        if p.driver == "serial":
            self._set_rate()
        self._last_connected: bool | None = None
        self.timer(1.0 / p.poll_hz, self.poll)
        self.service("probe/tare", Trigger, TriggerResult, self.on_tare)
        self.timer(1.0, self.publish_status, first_in_s=0.0)

    def _set_rate(self) -> None:
        try:
            self.driver.set_rate(self.params.rate_hz)
        except Exception as exc:  # the device may be absent now; the driver re-sends the rate on replug
            self.log.warning("could not set the sample rate yet: %s", exc)

    def on_tare(self, req: Trigger) -> TriggerResult:
        """Service ``probe/tare``: the current pose reads the calibration's zero heights from now on."""
        try:
            self.driver.zero()
        except FibreError as exc:
            raise RequestRefused(f"tare failed: {exc}") from None
        self.log.info("sensors tared")
        note = " (simulated sensors have no offset)" if self._sim is not None else ""
        return TriggerResult(message=f"tared{note}", state="ok")

    def on_pose(self, msg: RobotPose) -> None:
        if self._sim is not None:
            self._sim.set_pose(msg.stamp_ns, msg.x_mm, msg.y_mm, msg.z_mm)

    def on_pressure(self, msg: PressureState) -> None:
        if self._sim is not None:
            self._sim.set_pressure(msg.stamp_ns, msg.measured_kpa)

    def poll(self) -> None:
        samples = self.driver.read(0.0)
        if samples:
            self.publish_samples(samples)
        connected = self.driver.status().connected
        if connected != self._last_connected:
            self.publish_status()

    def publish_samples(self, samples: list[FibreSample]) -> None:
        h = np.array([s.heights_mm for s in samples], dtype=float)
        d_in, tilt = indentation_from_heights(h[:, 0], h[:, 1], h[:, 2], h[:, 3], self.params.sps_radius_mm,
                                              self.params.indenter_radius_mm)
        for s, d, t in zip(samples, np.atleast_1d(d_in).tolist(), np.atleast_1d(tilt).tolist(), strict=True):
            self.heights.publish(ProbeHeights(
                stamp_ns=s.stamp_ns or s.host_stamp_ns, seq=s.seq, h_mm=s.heights_mm, raw=s.raw,
                d_in_mm=d, tilt_rad=t, device_stamp_ns=s.device_stamp_ns,
            ))

    def publish_status(self) -> None:
        st = self.driver.status()
        if st.connected != self._last_connected:
            if st.connected:
                self.log.info("sensor up (%s)", st.port)
            elif self._last_connected is not None:
                self.log.warning("sensor DOWN (%s): %s", st.port, st.last_error)
        self._last_connected = st.connected
        self.status_pub.publish(DeviceStatus(
            stamp_ns=self.clock.now_ns(), device="fibre", connected=st.connected,
            state="ok" if st.connected else "down", message=st.last_error or "",
            counters={k: int(v) for k, v in dataclasses.asdict(st.counters).items()},
            clock_offset_ns=st.clock_offset_ns or 0,
        ))


if __name__ == "__main__":
    palpa.run_node(FibreReader)
