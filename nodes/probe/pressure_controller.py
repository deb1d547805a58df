"""Pressure regulator controller node: holds or ramps the air-float probe's pressure, never above its cap.

Commands arrive on ``pressure/command`` (hold a set-point, ramp at a rate to a target, vent). The node runs the
ramp itself (a set-point per control tick), clamps every set-point to ``max_kpa``, and watches the read-back: a
lost device, an over-pressure or a read-back far from the set-point for too long raises a fault on
``pressure/state`` and vents. ``driver: alicat`` talks to an Alicat controller over serial; ``driver: sim`` uses
the regulator plant model. ``pressure/state`` carries eq. 4's indentation force. The service ``pressure/set``
(:class:`SetPressure`) changes the set-point and answers with what the controller now follows; a set-point above
the cap is refused there (a caller must know), where a topic command is clamped.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import palpa
from messages import DeviceStatus, PressureAck, PressureCommand, PressureState, SetPressure
from messages.probe import PressureMode
from models.airfloat import ForceCalibration
from models.calibration_airfloat import CalibrationError, load_calibration
from nodes.drivers.pressure import (
    AlicatPressureDriver,
    PressureDriver,
    PressureError,
    PressureReading,
)
from nodes.drivers.pressure_sim import SimPressureDriver
from palpa.node.service import RequestRefused

__all__ = ["PressureController"]


class PressureController(palpa.Node):
    """Closed-loop supervision of an electronic pressure regulator."""

    class Params(palpa.Params):
        driver: Literal["sim", "alicat"] = "sim"
        max_kpa: palpa.SafetyLimit[palpa.Positive] = 60.0
        """Hard cap: no set-point above it is ever sent, whatever is commanded."""
        rate_hz: palpa.Positive = 50.0
        """Control/poll rate."""
        startup: Literal["vent", "hold", "ramp"] = "vent"
        setpoint_kpa: palpa.NonNegative = 0.0
        """Start-up set-point (hold) or ramp target."""
        ramp_rate_kpa_s: palpa.Positive = 5.0
        tracking_tolerance_kpa: palpa.SafetyLimit[palpa.Positive] = 3.0
        tracking_timeout_s: palpa.SafetyLimit[palpa.Positive] = 1.0
        """A read-back further than the tolerance from the set-point for this long is a fault."""
        lost_timeout_s: palpa.SafetyLimit[palpa.Positive] = 0.5
        """No read-back from the regulator this long is a fault (the device is lost)."""
        force_gain: float = 7.59
        force_offset: float = -2.34
        force_pressure_unit_kpa: palpa.Positive = 100.0
        """Eq. 4's pressure unit in kPa (100: the paper's P read as bar; see docs/physics.md)."""
        calibration: palpa.InputPath = ""
        """Calibration YAML (``python -m tools.calibrate_airfloat``): its force line replaces force_gain/offset."""
        port: str = "/dev/ttyUSB0"
        unit_id: str = "A"
        baudrate: palpa.PositiveInt = 19200
        sim_tau_s: palpa.Positive = 0.05
        sim_rate_limit_kpa_s: palpa.Positive = 50.0
        sim_noise_kpa: palpa.NonNegative = 0.05
        """Sim read-back white noise σ (kPa)."""
        sim_tracking_kpa: palpa.NonNegative = 0.25
        """Sim outlet wander about the set-point response, σ (kPa; 0: exact tracking, unit tests only)."""
        seed: int = 0
        """Seed of the sim regulator's noise and wander."""

    params: Params

    def setup(self) -> None:
        p = self.params
        if p.max_kpa <= 0:
            raise palpa.ParamError(f"{self.name}: max_kpa must be > 0")
        self.cal = ForceCalibration(p.force_gain, p.force_offset, p.force_pressure_unit_kpa)
        if p.calibration:
            try:
                self.cal = load_calibration(p.calibration).force
            except CalibrationError as exc:
                raise palpa.ParamError(f"{self.name}: calibration: {exc}") from None
            self.log.info("force line from %s: F = %.4f P/%g kPa %+.4f N", p.calibration, self.cal.gain,
                          self.cal.pressure_unit_kpa, self.cal.offset)
        self.state_pub = self.publisher("pressure/state", PressureState)
        self.status_pub = self.publisher("pressure/status", DeviceStatus, latched=True)
        self.driver: PressureDriver
        if p.driver == "sim":
            self.driver = self.closing(SimPressureDriver(
                self.clock.now_ns, p.max_kpa, tau_s=p.sim_tau_s, rate_limit_kpa_s=p.sim_rate_limit_kpa_s,
                noise_kpa=p.sim_noise_kpa, tracking_kpa=p.sim_tracking_kpa, seed=p.seed))
        else:
            # closed by the node whatever happens next, a failing setup() included (after on_shutdown's vent)
            self.driver = self.closing(AlicatPressureDriver(p.port, p.unit_id, p.max_kpa, p.baudrate,
                                                            require_device=False, clock=self.clock.now_ns))
        self.driver.open()
        self.mode: PressureMode = "vent"
        self.target = 0.0
        self.rate = 0.0
        self.setpoint = 0.0
        self.faults: list[str] = []
        self.last_ok_ns = self.clock.now_ns()
        self.off_since_ns: int | None = None
        self.last_reading: PressureReading | None = None
        self.subscribe("pressure/command", self.on_command)
        self.service("pressure/set", SetPressure, PressureAck, self.on_set)
        self.apply(PressureCommand(mode=p.startup, setpoint_kpa=p.setpoint_kpa, rate_kpa_s=p.ramp_rate_kpa_s))
        self.timer(1.0 / p.rate_hz, self.tick)
        self.timer(1.0, self.publish_status, first_in_s=0.0)

    # -- commands ----------------------------------------------------------------------------
    def on_command(self, cmd: PressureCommand) -> None:
        self.apply(cmd)

    def on_set(self, req: SetPressure) -> PressureAck:
        """Service ``pressure/set``: a set-point within [0, max_kpa], or a refusal that says why."""
        cap = self.params.max_kpa
        if not math.isfinite(req.setpoint_kpa) or req.setpoint_kpa < 0:
            raise palpa.ParamError(f"setpoint_kpa must be a number >= 0, got {req.setpoint_kpa}")
        if req.setpoint_kpa > cap:
            raise RequestRefused(f"set-point {req.setpoint_kpa:g} kPa is above the cap {cap:g} kPa: refused")
        if req.mode == "ramp" and not req.rate_kpa_s > 0:
            raise palpa.ParamError(f"rate_kpa_s must be > 0 for a ramp, got {req.rate_kpa_s}")
        self.apply(PressureCommand(mode=req.mode, setpoint_kpa=req.setpoint_kpa, rate_kpa_s=req.rate_kpa_s))
        return PressureAck(setpoint_kpa=self.setpoint, target_kpa=self.target, max_kpa=cap, mode=self.mode)

    def apply(self, cmd: PressureCommand) -> None:
        """Take a command; a set-point above the cap is clamped and reported as a fault flag."""
        self.faults = [f for f in self.faults if f == "device_lost"]
        target = max(0.0, cmd.setpoint_kpa)
        if target > self.params.max_kpa:
            self.log.warning("commanded %.2f kPa is above the cap %.2f kPa: clamped", target, self.params.max_kpa)
            self.faults.append("clamped")
            target = self.params.max_kpa
        self.mode = cmd.mode
        if cmd.mode == "vent":
            self.target = self.setpoint = 0.0
        elif cmd.mode == "hold":
            self.target = self.setpoint = target
        else:
            if cmd.rate_kpa_s <= 0:
                self.log.warning("ramp with rate %.3f kPa/s ignored: rate must be > 0", cmd.rate_kpa_s)
                return
            self.target, self.rate = target, cmd.rate_kpa_s
            self.setpoint = self.last_reading.measured_kpa if self.last_reading else self.setpoint
        self.off_since_ns = None
        self._send(self.setpoint)

    def _send(self, kpa: float) -> None:
        kpa = min(max(kpa, 0.0), self.params.max_kpa)  # belt and braces: the driver clamps too
        try:
            self.last_reading = self.driver.set_setpoint(kpa)
            self.last_ok_ns = self.clock.now_ns()
        except PressureError as exc:
            self.log.warning("set-point %.2f kPa not sent: %s", kpa, exc)

    # -- control loop ------------------------------------------------------------------------
    def tick(self) -> None:
        now = self.clock.now_ns()
        if self.mode == "ramp":
            step = self.rate / self.params.rate_hz
            if abs(self.target - self.setpoint) <= step:
                self.setpoint = self.target
                self.mode = "hold"
            else:
                self.setpoint += step if self.target > self.setpoint else -step
            self._send(self.setpoint)
        try:
            reading = self.driver.read(0.2)
        except PressureError as exc:
            reading = None
            self.log.debug("read failed: %s", exc)
        if reading is not None:
            self.last_reading = reading
            self.last_ok_ns = now
            self._drop_fault("device_lost")
        elif (now - self.last_ok_ns) / 1e9 > self.params.lost_timeout_s:
            self._fault("device_lost", "no read-back from the regulator")
        self._check(now)
        self.publish_state(now)

    def _check(self, now: int) -> None:
        r = self.last_reading
        if r is None:
            return
        p = self.params
        if r.measured_kpa > p.max_kpa + p.tracking_tolerance_kpa:
            self._fault("over_pressure", f"measured {r.measured_kpa:.2f} kPa above the cap {p.max_kpa:.2f} kPa")
        if self.mode in ("hold", "vent") and abs(r.measured_kpa - self.setpoint) > p.tracking_tolerance_kpa:
            self.off_since_ns = self.off_since_ns or now
            if (now - self.off_since_ns) / 1e9 > p.tracking_timeout_s:
                self._fault("tracking_error",
                            f"read-back {r.measured_kpa:.2f} kPa vs set-point {self.setpoint:.2f} kPa")
        else:
            self.off_since_ns = None

    def _fault(self, name: str, why: str) -> None:
        if name in self.faults:
            return
        self.faults.append(name)
        self.log.error("FAULT %s: %s; venting", name, why)
        self.mode, self.target, self.setpoint = "vent", 0.0, 0.0
        self._send(0.0)

    def _drop_fault(self, name: str) -> None:
        if name in self.faults:
            self.faults.remove(name)
            self.log.info("fault %s cleared", name)

    def publish_state(self, now: int) -> None:
        r = self.last_reading
        measured = r.measured_kpa if r is not None else 0.0
        self.state_pub.publish(PressureState(
            stamp_ns=r.stamp_ns if r is not None else now, setpoint_kpa=self.setpoint, measured_kpa=measured,
            force_n=float(self.cal.force_n(measured)), mode=self.mode, max_kpa=self.params.max_kpa,
            faults=list(self.faults),
        ))

    def publish_status(self) -> None:
        st = self.driver.status()
        self.status_pub.publish(DeviceStatus(
            stamp_ns=self.clock.now_ns(), device="pressure", connected=st.connected,
            state="fault" if self.faults else ("ok" if st.connected else "down"),
            message="; ".join(self.faults) or (st.last_error or ""),
            counters={k: int(v) for k, v in dataclasses.asdict(st.counters).items()},
        ))

    def on_shutdown(self) -> None:
        try:
            self.driver.vent()
        except PressureError as exc:
            self.log.warning("could not vent on shutdown: %s", exc)


if __name__ == "__main__":
    palpa.run_node(PressureController)
