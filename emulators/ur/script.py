"""URScript received on the script port (30003) and the one program the emulator runs.

The emulator does not interpret URScript in general. It recognises the control script that
ur_rtde uploads (`def rtde_control():`) and runs an equivalent of its main loop natively:
a command id arrives in `input_int_register_0` (+ offset) with arguments in the input
double/int registers, and the program answers on `output_int_register_0` (1 ready, 2 done)
and reports async progress in `output_int_register_2`. A moveL path arrives as one
`movel(p[...], a=..., v=..., r=...)` line per waypoint injected into `exec_move_path()`.

URScript threads are emulated as Python generators: each `yield` is one `sync()`, i.e. one
2 ms controller tick. Commands the emulator does not model stop the program with a runtime
error (logged), as an unknown function would on a real controller, instead of pretending.
"""

from __future__ import annotations

import math
import re
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from typing import Protocol

from models.arm import ArmModel, ArmTarget, Pose

Tick = Generator[None, None, None]

# command ids of ur_rtde's RTDE::RobotCommand::Type that the emulated script understands
CMD_MOVEL, CMD_SPEEDL, CMD_SPEED_STOP, CMD_PROTECTIVE_STOP = 3, 10, 15, 31
CMD_STOPL, CMD_STOPJ, CMD_SET_WATCHDOG, CMD_MOVE_PATH, CMD_IS_STEADY = 33, 34, 35, 45, 47
CMD_ZERO_FT, CMD_SET_PAYLOAD, CMD_GET_STEPTIME, CMD_GET_TARGET_WAYPOINT = 8, 17, 26, 28
CMD_STOP_SCRIPT = 255
# commands the real script treats as realtime: processed and answered "ready" at once
REALTIME_CMDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_MOVE_RE = re.compile(rf"^\s*(movel|movep|movej)\((p?)\[([^\]]*)\]\s*,\s*a\s*=\s*({_NUM})\s*,\s*v\s*=\s*({_NUM})\s*,\s*r\s*=\s*({_NUM})\s*\)\s*$")


class ScriptError(Exception):
    """A runtime error of the emulated program (stops the program, like on a controller)."""


@dataclass(frozen=True)
class PathMove:
    """One injected path line: kind ('movel', 'movep' or 'movej'), 6 numbers in SI units
    (m and rad for poses, rad for joints), a (m/s^2), v (m/s), r (m)."""

    kind: str
    is_pose: bool
    values: tuple[float, ...]
    a: float
    v: float
    r: float


class ScriptReceiver:
    """Splits the byte stream of the script port into programs (`def name():` ... `end`,
    also `sec`) and single statements sent outside any program."""

    def __init__(self) -> None:
        self._buf = ""
        self._program: list[str] | None = None

    def feed(self, text: str) -> Iterator[tuple[str, str]]:
        """Yield ("program", source) or ("statement", line) for every complete unit."""
        self._buf += text
        while "\n" in self._buf:
            line, self._buf = self._buf.split("\n", 1)
            line = line.rstrip("\r")
            if self._program is not None:
                self._program.append(line)
                if line.strip() == "end" and not line[:1].isspace():
                    yield "program", "\n".join(self._program) + "\n"
                    self._program = None
            elif re.match(r"^(def|sec)\s+\w+\s*\(\s*\)\s*:", line):
                self._program = [line]
            elif line.strip():
                yield "statement", line.strip()


def program_name(source: str) -> str:
    m = re.match(r"^(?:def|sec)\s+(\w+)", source)
    return m.group(1) if m else "<unnamed>"


def parse_path(source: str) -> list[PathMove]:
    """The move lines injected after `# inject move path` inside `exec_move_path()`."""
    start = source.find("# inject move path")
    if start < 0:
        return []
    moves = []
    for line in source[start:].splitlines()[1:]:
        text = line.strip()
        if not text or text.startswith("signal_async_progress") or text.startswith("#"):
            continue
        m = _MOVE_RE.match(text)
        if not m:
            break  # end of the injected block
        values = tuple(float(x) for x in m.group(3).split(","))
        if len(values) != 6:
            raise ScriptError(f"path line needs 6 numbers: {text!r}")
        moves.append(PathMove(m.group(1), m.group(2) == "p", values, float(m.group(4)), float(m.group(5)), float(m.group(6))))
    return moves


class ScriptHost(Protocol):
    """What a running program needs from its controller (:class:`emulators.ur.controller.UrController`
    provides it; the controller imports this module, never the other way round). The caller holds its lock."""

    arm: ArmModel
    in_int: list[int]
    in_double: list[float]
    out_int: list[int]
    out_double: list[float]

    def log(self, message: str) -> None: ...

    def start_motion(self, targets: list[ArmTarget]) -> None: ...

    def note_motion_start(self) -> None: ...

    def protective_stop(self, reason: str) -> None: ...

    def set_watchdog(self, input_name: str, min_hz: float) -> None: ...

    def zero_ft_sensor(self) -> None: ...

    @property
    def input_writes(self) -> int: ...

    def written_since(self, name: str, writes: int) -> bool: ...


class RtdeControlProgram:
    """Native equivalent of ur_rtde's `rtde_control` script (main loop, move/stop threads)."""

    def __init__(self, source: str, ctl: ScriptHost) -> None:
        self.name = program_name(source)
        self.ctl = ctl
        # ur_rtde injects the offsets after a comment that ends the `... =` line, so the
        # number starts the next line: "global reg_offset_int = # int register offset\n24"
        off_f = re.search(r"global reg_offset_float\s*=\s*(?:#[^\n]*\n)?\s*(\d+)", source)
        off_i = re.search(r"global reg_offset_int\s*=\s*(?:#[^\n]*\n)?\s*(\d+)", source)
        self.off_f = int(off_f.group(1)) if off_f else 0
        self.off_i = int(off_i.group(1)) if off_i else 0
        self.path = parse_path(source)
        # a command written before this program arrived was for the one it replaces (ur_rtde's stop script): a
        # controller takes long enough to start a program that the client has cleared it by then; this one starts
        # within milliseconds and its threads may read the script before the clear, so it ignores such a command
        self._cmd_register = f"input_int_register_{self.off_i}"
        self._born = ctl.input_writes
        self.async_count = 0
        self.async_op = 0
        self.threads: dict[str, Tick] = {}
        self._main = self._main_loop()

    # ------------------------------------------------------------ registers
    def in_int(self, i: int) -> int:
        return self.ctl.in_int[i + self.off_i]

    def in_float(self, i: int) -> float:
        return self.ctl.in_double[i + self.off_f]

    def out_int(self, i: int, value: int) -> None:
        self.ctl.out_int[i + self.off_i] = int(value)

    def out_float(self, i: int, value: float) -> None:
        self.ctl.out_double[i + self.off_f] = float(value)

    def pose_from_floats(self, i: int) -> Pose:
        """Pose registers (m, rad) -> pose in mm, rad."""
        p = [self.in_float(i + k) for k in range(6)]
        return (p[0] * 1000, p[1] * 1000, p[2] * 1000, p[3], p[4], p[5])

    def signal_async(self, value: int) -> None:
        """write_async_progress_register: change count in bits 16-22, operation id in bits
        24-30, bit 15 = running, progress in bits 0-14; value < 0 means finished."""
        self.async_count = (self.async_count + 1) % 128
        if value == 0:
            self.async_op = (self.async_op + 1) % 128
        reg = self.async_count * 65536 + self.async_op * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int(2, reg)

    # ------------------------------------------------------------ scheduling
    def step(self) -> bool:
        """Run one tick of every thread; False once the program has ended."""
        for name, thread in list(self.threads.items()):
            try:
                next(thread)
            except StopIteration:
                self.threads.pop(name, None)
        try:
            next(self._main)
        except StopIteration:
            return False
        return True

    def kill(self, name: str) -> bool:
        return self.threads.pop(name, None) is not None

    # ------------------------------------------------------------ the script
    def _main_loop(self) -> Tick:
        self.signal_async(-1)
        self.out_int(0, 1)
        executing = False
        while True:
            cmd = self.in_int(0) if self.ctl.written_since(self._cmd_register, self._born) else 0
            if cmd in REALTIME_CMDS:
                yield from self._process(cmd)
                self.out_int(0, 1)
            elif cmd == 0:
                executing = False
                self.out_int(0, 1)
            elif not executing:
                executing = True
                if cmd == CMD_STOP_SCRIPT:
                    self.ctl.log("rtde_control: received stop script")
                    return
                yield from self._process(cmd)
                self.out_int(0, 2)
            yield

    def _wait_arm(self) -> Tick:
        while self.ctl.arm.is_moving:
            yield

    def _stop_async_move(self) -> None:
        if self.kill("move"):
            self.signal_async(-1)

    def _move_thread(self, targets: list[ArmTarget], report_index: bool) -> Tick:
        self.signal_async(0)
        self.ctl.start_motion(targets)
        last = -1
        while self.ctl.arm.is_moving:
            if report_index and self.ctl.arm.path_index != last:
                last = self.ctl.arm.path_index
                self.signal_async(last)
            yield
        self.threads.pop("move", None)
        self.signal_async(-1)

    def _stop_thread(self, decel_mm_s2: float) -> Tick:
        self.signal_async(0)
        self.ctl.arm.stop_l(decel_mm_s2)
        yield from self._wait_arm()
        self.threads.pop("stop", None)
        self.signal_async(-1)

    def _path_targets(self) -> list[ArmTarget]:
        targets = []
        for i, m in enumerate(self.path):
            if m.kind == "movej" or not m.is_pose:
                raise ScriptError(f"path line {i}: {m.kind} with joint positions needs joint kinematics, "
                                  "which this emulator does not model (use movel with poses)")
            x = m.values
            targets.append(ArmTarget((x[0] * 1000, x[1] * 1000, x[2] * 1000, x[3], x[4], x[5]),
                                     m.v * 1000, m.a * 1000, m.r * 1000))
        if not targets:
            raise ScriptError("move path command, but no path was injected into the script")
        return targets

    def _process(self, cmd: int) -> Tick:
        ctl = self.ctl
        if cmd in (CMD_MOVEL, CMD_MOVE_PATH):
            if cmd == CMD_MOVEL:
                pose = self.pose_from_floats(0)
                v, a = self.in_float(6) * 1000, self.in_float(7) * 1000
                targets = [ArmTarget(pose, v, a)]
            else:
                targets = self._path_targets()
            self._stop_async_move()
            if self.in_int(1) == 1:
                self.threads["move"] = self._move_thread(targets, report_index=cmd == CMD_MOVE_PATH)
            else:
                ctl.start_motion(targets)
                yield from self._wait_arm()
        elif cmd in (CMD_STOPL, CMD_STOPJ):
            decel = self.in_float(0) * 1000
            if not (math.isfinite(decel) and decel > 0):
                raise ScriptError(f"stopl: deceleration must be > 0, got {decel / 1000} m/s^2")
            stop_move = not self.kill("stop")
            if stop_move:
                self._stop_async_move()
            else:
                self.signal_async(-1)
            if self.in_int(1) == 1:
                self.threads["stop"] = self._stop_thread(decel)
            else:
                ctl.arm.stop_l(decel)
                yield from self._wait_arm()
        elif cmd == CMD_SPEEDL:
            xd = [self.in_float(k) for k in range(6)]
            accel = self.in_float(6) * 1000
            self._stop_async_move()
            ctl.note_motion_start()
            ctl.arm.speed_l([xd[0] * 1000, xd[1] * 1000, xd[2] * 1000, xd[3], xd[4], xd[5]], accel)
        elif cmd == CMD_SPEED_STOP:
            ctl.arm.stop_l(self.in_float(0) * 1000)
            yield from self._wait_arm()
        elif cmd == CMD_PROTECTIVE_STOP:
            ctl.protective_stop("protective_stop() called by the control script")
        elif cmd == CMD_SET_WATCHDOG:
            ctl.set_watchdog(f"input_int_register_{self.off_i}", self.in_float(0))
        elif cmd == CMD_IS_STEADY:
            self.out_int(1, 0 if ctl.arm.is_moving else 1)
        elif cmd == CMD_GET_STEPTIME:
            self.out_float(0, 0.002)
        elif cmd == CMD_GET_TARGET_WAYPOINT:
            p = ctl.arm.pose
            for k, v in enumerate((p[0] / 1000, p[1] / 1000, p[2] / 1000, p[3], p[4], p[5])):
                self.out_float(k, v)
        elif cmd == CMD_ZERO_FT:
            ctl.zero_ft_sensor()
        elif cmd == CMD_SET_PAYLOAD:
            ctl.log(f"set_payload({self.in_float(0)} kg) accepted (payload is not modelled)")
        else:
            raise ScriptError(f"command {cmd} of the rtde_control script is not emulated")
