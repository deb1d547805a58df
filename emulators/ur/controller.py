"""The emulated controller: arm model, RTDE registers, program, safety state, faults.

No sockets here (see server.py). Every method expects the caller to hold `lock`; `tick()`
advances everything by one 2 ms controller cycle. What the tip feels of the specimen and what
the force sensor reads are in contact.py.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from emulators.ur.contact import (  # BACKING_N_PER_MM, SurfaceLike: re-exported, they were defined here
    BACKING_N_PER_MM as BACKING_N_PER_MM,
)
from emulators.ur.contact import ForceSensor, SpecimenContact
from emulators.ur.contact import SurfaceLike as SurfaceLike
from emulators.ur.rtde import OUTPUT_TYPES
from emulators.ur.script import RtdeControlProgram, ScriptError, program_name
from models.arm import TICK_S, ArmModel, ArmTarget, Pose

RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2  # RTDE runtime_state (0, "stopping", is never reported here)
ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP = 1, 3
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE_STOP, SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 1 << 0, 1 << 2, 1 << 10
ROBOT_BIT_POWER_ON, ROBOT_BIT_PROGRAM_RUNNING = 1 << 0, 1 << 1


@dataclass
class ControllerConfig:
    """Identity and limits of the emulated controller. Poses in mm and rad."""

    controller_version: tuple[int, int, int, int] = (5, 11, 1, 108318)
    serial_number: str = "20235500001"
    robot_model: str = "UR5"
    home_pose: Pose = (300.0, 0.0, 300.0, 0.0, math.pi, 0.0)
    max_speed_mm_s: float = 1000.0
    max_accel_mm_s2: float = 5000.0
    stop_decel_mm_s2: float = 3000.0  # program stop and protective stop deceleration
    remote_control: bool = True
    unlock_delay_s: float = 5.0  # a real controller refuses to unlock a protective stop sooner
    program_start_s: float = 0.01  # time between receiving a program and PLAYING
    force_limit_n: float = 150.0  # contact force that triggers a protective stop
    tip_radius_mm: float = 3.5  # spherical probe tip for the contact model
    phantom_origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)  # phantom frame origin in base
    force_noise_n: float = 1.0
    """The TCP force sensor's reading noise, sigma (N) per 2 ms sample and force axis. A UR's built-in sensor is
    coarse: the UR5e datasheet gives a force precision of 3.5 N and an accuracy of 4 N, and a CB3 user measured a
    sigma of 3.6 N; 1 N is at the kind end. A wrist F/T sensor (an ATI Nano17 resolves ~3 mN) is ~0.01 N."""
    force_bias_n: float = 3.0
    """Its offset until zero_ftsensor(): each force axis off by up to this (N), drawn from ``sensor_seed``."""
    sensor_seed: int = 0


@dataclass
class FaultPlan:
    """Faults fired once, timed from the start of the first motion after `arm_faults`.
    Waypoints count along that motion's path (n = n waypoints reached)."""

    pstop_after_waypoints: int | None = None
    pstop_at_s: float | None = None
    drop_at_s: float | None = None
    refuse_s: float = 0.0  # after a drop, refuse new connections this long
    pause_stream_at_s: float | None = None
    pause_stream_for_s: float = 1.0
    fired: set[str] = field(default_factory=set)


class UrController:
    """State of one emulated UR controller (see module docstring for the locking rule)."""

    def __init__(self, config: ControllerConfig | None = None, phantom: SurfaceLike | None = None,
                 log: Callable[[str], None] | None = None) -> None:
        self.config = config or ControllerConfig()
        self.lock = threading.RLock()
        self.phantom = phantom
        self.arm = ArmModel(self.config.home_pose, max_speed_mm_s=self.config.max_speed_mm_s,
                            max_accel_mm_s2=self.config.max_accel_mm_s2)
        self.in_int = [0] * 48
        self.in_double = [0.0] * 48
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.remote_control = self.config.remote_control
        self.program: RtdeControlProgram | None = None
        self.last_program_source = ""
        self._starting: tuple[int, RtdeControlProgram] | None = None
        self._ticks = 0
        self.protective_stopped = False
        self._pstop_tick = 0
        self.force = [0.0] * 6
        """The true contact force on the tip (N); what the sensor reads of it is :meth:`sensed_force`."""
        self._contact = SpecimenContact(phantom) if phantom is not None else None
        self._sensor = ForceSensor(self.config.force_bias_n, self.config.sensor_seed)
        self._watchdog: tuple[str, int] | None = None
        self._input_tick: dict[str, int] = {}
        self.input_writes = 0  # input data packages applied so far
        self._input_write: dict[str, int] = {}  # input -> the package that last wrote it
        self.faults: FaultPlan | None = None
        self._fault_t0: int | None = None
        self.stream_paused_until = 0
        self.on_drop: Callable[[float], None] | None = None
        self.messages: deque[str] = deque(maxlen=500)
        self._log_sink = log

    # ------------------------------------------------------------------ misc
    @property
    def ticks(self) -> int:
        """Controller cycles run: the controller's time (RTDE's timestamp) in 2 ms."""
        return self._ticks

    @property
    def arm_steps(self) -> int:
        """Cycles the arm moved in: :attr:`ticks` less those it was held (``tick(hold=True)``)."""
        return self.arm.ticks

    def log(self, message: str) -> None:
        line = f"[{self.ticks * TICK_S:9.3f}] {message}"
        self.messages.append(line)
        if self._log_sink is not None:
            self._log_sink(line)

    @property
    def runtime_state(self) -> int:
        return RUNTIME_PLAYING if self.program is not None else RUNTIME_STOPPED

    @property
    def safety_status_bits(self) -> int:
        if self.protective_stopped:
            return SAFETY_BIT_PROTECTIVE_STOP | SAFETY_BIT_STOPPED_DUE_TO_SAFETY
        return SAFETY_BIT_NORMAL

    @property
    def safety_mode(self) -> int:
        return SAFETY_MODE_PROTECTIVE_STOP if self.protective_stopped else SAFETY_MODE_NORMAL

    @property
    def robot_status_bits(self) -> int:
        return ROBOT_BIT_POWER_ON | (ROBOT_BIT_PROGRAM_RUNNING if self.program is not None else 0)

    # -------------------------------------------------------------- programs
    def submit_program(self, source: str) -> None:
        """A program arrived on the script port: replace the running one after a short start delay."""
        name = program_name(source)
        self.last_program_source = source
        if not self.remote_control:
            self.log(f"program {name!r} ignored: the robot is in local control")
            return
        if self.protective_stopped:
            self.log(f"program {name!r} not started: protective stop active")
            return
        if name != "rtde_control":
            self.log(f"program {name!r} ignored: only ur_rtde's rtde_control script is emulated")
            return
        if self.program is not None:
            self.end_program(f"replaced by new program {name!r}")
        try:
            program = RtdeControlProgram(source, self)
        except ScriptError as e:
            self.log(f"program {name!r} rejected: {e}")
            return
        self._starting = (self.ticks + max(1, round(self.config.program_start_s / TICK_S)), program)
        self.log(f"program {name!r} received ({len(program.path)} path moves)")

    def run_statement(self, line: str) -> None:
        """A single statement on the script port runs as a program of its own, so it ends the
        running program; stopl/stopj also decelerate the arm, anything else is only logged."""
        if not self.remote_control:
            self.log(f"statement ignored (local control): {line}")
            return
        if self.program is not None:
            self.end_program(f"statement {line!r} replaced the program")
        head = line.split("(", 1)[0].strip()
        if head in ("stopl", "stopj"):
            try:
                decel = float(line.split("(", 1)[1].split(")", 1)[0].split(",")[0]) * 1000
                self.arm.stop_l(decel)
            except (IndexError, ValueError) as e:
                self.log(f"statement {line!r} failed: {e}")
        else:
            self.log(f"statement not emulated: {line}")

    def end_program(self, reason: str) -> None:
        """Stop the running (or starting) program; a moving arm decelerates to rest."""
        self._starting = None
        if self.program is None:
            return
        self.program = None
        self._watchdog = None
        if self.arm.is_moving:
            self.arm.stop_l(self.config.stop_decel_mm_s2)
        self.log(f"program stopped: {reason}")

    def start_motion(self, targets: list[ArmTarget]) -> None:
        self.note_motion_start()
        self.arm.move_path(targets)

    def note_motion_start(self) -> None:
        if self.faults is not None and self._fault_t0 is None:
            self._fault_t0 = self.ticks

    # ---------------------------------------------------------------- safety
    def protective_stop(self, reason: str) -> None:
        if self.protective_stopped:
            return
        self.protective_stopped = True
        self._pstop_tick = self.ticks
        self.log(f"PROTECTIVE STOP: {reason}")
        self.end_program("protective stop")
        if self.arm.is_moving:
            self.arm.stop_l(self.config.stop_decel_mm_s2)

    def unlock_protective_stop(self) -> str:
        """Dashboard `unlock protective stop`: the reply text of a real controller."""
        if self.protective_stopped and (self.ticks - self._pstop_tick) * TICK_S < self.config.unlock_delay_s:
            return ("Cannot unlock protective stop until 5s after occurrence. "
                    "Always inspect cause of protective stop before unlocking")
        if self.protective_stopped:
            self.protective_stopped = False
            self.log("protective stop released")
        return "Protective stop releasing"

    def set_watchdog(self, input_name: str, min_hz: float) -> None:
        """rtde_set_watchdog(input, min_hz, "stop"): stop the program when the input is not
        written by an RTDE client at least min_hz times per second."""
        if not (math.isfinite(min_hz) and min_hz > 0):
            self._watchdog = None
            return
        self._watchdog = (input_name, max(1, math.ceil(1.0 / (min_hz * TICK_S))))
        self._input_tick[input_name] = self.ticks
        self.log(f"RTDE watchdog on {input_name}: at least {min_hz:g} Hz")

    def zero_ft_sensor(self) -> None:
        """URScript's zero_ftsensor(): the reading now (its noise included) becomes the zero."""
        self._sensor.zero(self.force)

    def _raw_force(self) -> tuple[float, ...]:
        """The sensor's reading before zeroing: the contact force, its bias and this cycle's noise."""
        return self._sensor.raw(self.force)

    def sensed_force(self) -> tuple[float, ...]:
        """actual_TCP_force: what the sensor reads (``force`` is the true contact force)."""
        return self._sensor.sensed(self.force)

    def arm_faults(self, plan: FaultPlan | None) -> None:
        self.faults, self._fault_t0 = plan, None

    # ------------------------------------------------------------------ RTDE
    def write_inputs(self, names: Sequence[str], values: Sequence[object]) -> None:
        self.input_writes += 1
        for name, value in zip(names, values, strict=True):
            self._input_tick[name] = self.ticks
            self._input_write[name] = self.input_writes
            if name.startswith("input_int_register_"):
                self.in_int[int(name.rsplit("_", 1)[1])] = int(value)  # type: ignore[call-overload]
            elif name.startswith("input_double_register_"):
                self.in_double[int(name.rsplit("_", 1)[1])] = float(value)  # type: ignore[arg-type]

    def written_since(self, name: str, writes: int) -> bool:
        """Whether input ``name`` was written after the first ``writes`` input packages."""
        return self._input_write.get(name, 0) > writes

    def output(self, name: str) -> object:
        """Current value of an RTDE output field, in UR's units (m, rad, N, s)."""
        return self.getter(name)()

    def getter(self, name: str) -> Callable[[], object]:
        """A function returning the current value of RTDE output `name` (resolved once per
        recipe, so streaming 500 packages a second costs one call per field)."""
        arm = self.arm
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            return lambda: tuple(v / 1000 if i < 3 else v for i, v in enumerate(arm.pose))
        if name in ("actual_TCP_speed", "target_TCP_speed"):
            return lambda: tuple(v / 1000 if i < 3 else v for i, v in enumerate(arm.tcp_speed))
        if name == "actual_TCP_force":
            return self.sensed_force
        if name == "ft_raw_wrench":
            return self._raw_force
        dynamic: dict[str, Callable[[], object]] = {
            "timestamp": lambda: self.ticks * TICK_S,
            "runtime_state": lambda: self.runtime_state,
            "robot_status_bits": lambda: self.robot_status_bits,
            "safety_status_bits": lambda: self.safety_status_bits,
            "safety_mode": lambda: self.safety_mode,
            "safety_status": lambda: self.safety_mode,
            "tcp_force_scalar": lambda: math.hypot(*self.sensed_force()[:3]),
        }
        if name in dynamic:
            return dynamic[name]
        constant: dict[str, object] = {
            "robot_mode": ROBOT_MODE_RUNNING, "speed_scaling": 1.0, "target_speed_fraction": 1.0,
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0, "joint_mode": (253,) * 6,
            "joint_temperatures": (30.0,) * 6, "actual_joint_voltage": (48.0,) * 6,
        }
        if name in constant:
            value = constant[name]
            return lambda: value
        kind, _, idx = name.rpartition("_")
        registers: dict[str, list[int] | list[float]] = {
            "output_int_register": self.out_int, "output_double_register": self.out_double,
            "input_int_register": self.in_int, "input_double_register": self.in_double}
        if kind in registers:
            regs, i = registers[kind], int(idx)
            return lambda: regs[i]
        t = OUTPUT_TYPES[name]  # not modelled (joints, I/O, ...): a zero of the right shape
        width = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6}.get(t, 0)
        zero: object = 0.0 if t in ("DOUBLE", "VECTOR3D", "VECTOR6D") else (False if t == "BOOL" else 0)
        fixed = (zero,) * width if width else zero
        return lambda: fixed

    # ------------------------------------------------------------------ tick
    def tick(self, *, hold: bool = False) -> None:
        """One 2 ms controller cycle: start/run the program, move the arm (unless ``hold``: the emulator's
        motion waits for an external clock), faults, contact."""
        if self._starting is not None and self.ticks >= self._starting[0]:
            self.program, self._starting = self._starting[1], None
            self.log(f"program {self.program.name!r} playing")
        if self._watchdog is not None and self.program is not None:
            name, limit = self._watchdog
            if self.ticks - self._input_tick.get(name, 0) > limit:
                self.end_program(f"RTDE watchdog: {name} not updated for {limit * TICK_S:.3f} s")
        if self.program is not None:
            try:
                alive = self.program.step()
            except ScriptError as e:
                self.end_program(f"runtime error: {e}")
            else:
                if not alive:
                    self.end_program("program finished")
        self._ticks += 1
        if not hold:
            self.arm.step(TICK_S)
        self._check_faults()
        self._update_force()

    def _check_faults(self) -> None:
        plan, t0 = self.faults, self._fault_t0
        if plan is None or t0 is None:
            return
        elapsed = (self.ticks - t0) * TICK_S

        def due(key: str, when: float | None) -> bool:
            if when is None or key in plan.fired or elapsed < when:
                return False
            plan.fired.add(key)
            return True

        n = plan.pstop_after_waypoints
        if n is not None and "pstop_wp" not in plan.fired and self.arm.is_moving and self.arm.path_index >= n:
            plan.fired.add("pstop_wp")
            self.protective_stop(f"injected fault: protective stop after {n} waypoints")
        if due("pstop_t", plan.pstop_at_s):
            self.protective_stop(f"injected fault: protective stop {plan.pstop_at_s} s into the motion")
        if due("pause", plan.pause_stream_at_s):
            self.pause_streaming(plan.pause_stream_for_s)
        if due("drop", plan.drop_at_s):
            self.log(f"injected fault: dropping all connections (refusing for {plan.refuse_s} s)")
            if self.on_drop is not None:
                self.on_drop(plan.refuse_s)

    def pause_streaming(self, duration_s: float) -> None:
        self.stream_paused_until = self.ticks + math.ceil(duration_s / TICK_S)
        self.log(f"RTDE streaming paused for {duration_s} s")

    def _update_force(self) -> None:
        self._sensor.draw_noise(self.config.force_noise_n)
        if self._contact is None:
            return
        c = self.config
        fz = self._contact.press_force(self.arm.pose, c.phantom_origin_mm, c.tip_radius_mm)
        self.force = [0.0, 0.0, fz, 0.0, 0.0, 0.0]
        if fz > c.force_limit_n:
            self.protective_stop(f"contact force {fz:.1f} N exceeds the {c.force_limit_n:g} N limit")
