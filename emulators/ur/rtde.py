"""RTDE (Real-Time Data Exchange, TCP port 30004) server side, protocol versions 1 and 2.

Framing: every message is `uint16 size, uint8 type, payload`, big-endian, where size counts
the 3 header bytes. A client negotiates the protocol version (`V`), may ask the controller
version (`v`), sets up one output recipe (`O`: frequency + comma-separated field names) and
any number of input recipes (`I`), then starts (`S`) or pauses (`P`) the stream. While
started the server sends `U` data packages (recipe id + packed fields) at the recipe's rate
and the client sends `U` packages (input recipe id + packed fields) to write inputs.
Input recipe ids are handed out 1, 2, 3... per connection in arrival order; ur_rtde relies
on that. Unknown field names answer `NOT_FOUND` (and recipe id 0). Each field is packed
with UR's own type for it (table below, from UR's RTDE guide).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

MSG_PROTOCOL_VERSION = ord("V")
MSG_CONTROLLER_VERSION = ord("v")
MSG_TEXT = ord("M")
MSG_SETUP_OUTPUTS = ord("O")
MSG_SETUP_INPUTS = ord("I")
MSG_START = ord("S")
MSG_PAUSE = ord("P")
MSG_DATA = ord("U")

HEADER = struct.Struct(">HB")
MAX_RATE_HZ = 500.0

TYPE_FORMATS: dict[str, str] = {
    "BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
    "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I",
}


def _output_types() -> dict[str, str]:
    t: dict[str, str] = {}
    for name in ("target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
                 "actual_qd", "actual_current", "joint_control_output", "actual_TCP_pose",
                 "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed",
                 "joint_temperatures", "actual_joint_voltage", "ft_raw_wrench", "payload_inertia",
                 "actual_current_as_torque"):
        t[name] = "VECTOR6D"
    for name in ("timestamp", "actual_execution_time", "speed_scaling", "target_speed_fraction",
                 "actual_momentum", "actual_main_voltage", "actual_robot_voltage", "actual_robot_current",
                 "standard_analog_input0", "standard_analog_input1", "standard_analog_output0",
                 "standard_analog_output1", "io_current", "tool_analog_input0", "tool_analog_input1",
                 "tool_output_current", "tool_temperature", "payload", "tcp_force_scalar"):
        t[name] = "DOUBLE"
    for name in ("actual_tool_accelerometer", "elbow_position", "elbow_velocity", "payload_cog"):
        t[name] = "VECTOR3D"
    for name in ("runtime_state", "robot_status_bits", "safety_status_bits", "analog_io_types", "tool_mode",
                 "tool_analog_input_types", "output_bit_registers0_to_31", "output_bit_registers32_to_63",
                 "input_bit_registers0_to_31", "input_bit_registers32_to_63"):
        t[name] = "UINT32"
    for name in ("robot_mode", "safety_mode", "safety_status", "tool_output_voltage"):
        t[name] = "INT32"
    t["actual_digital_input_bits"] = t["actual_digital_output_bits"] = "UINT64"
    t["joint_mode"] = "VECTOR6INT32"
    for name in ("tool_output_mode", "tool_digital_output0_mode", "tool_digital_output1_mode"):
        t[name] = "UINT8"
    for i in range(48):
        t[f"output_int_register_{i}"] = t[f"input_int_register_{i}"] = "INT32"
        t[f"output_double_register_{i}"] = t[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        t[f"output_bit_register_{i}"] = t[f"input_bit_register_{i}"] = "BOOL"
    return t


def _input_types() -> dict[str, str]:
    t: dict[str, str] = {
        "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
        "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
        "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
        "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
        "external_force_torque": "VECTOR6D",
    }
    for i in range(48):
        t[f"input_int_register_{i}"] = "INT32"
        t[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        t[f"input_bit_register_{i}"] = "BOOL"
    return t


OUTPUT_TYPES = _output_types()
INPUT_TYPES = _input_types()


def frame(msg_type: int, payload: bytes = b"") -> bytes:
    """One RTDE message: header (size incl. header, type) + payload."""
    return HEADER.pack(HEADER.size + len(payload), msg_type) + payload


def recipe_struct(types: Sequence[str]) -> struct.Struct:
    """Big-endian struct for a recipe's packed fields (without the leading recipe id)."""
    return struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types))


def flatten(values: Sequence[object]) -> list[object]:
    """Spread vector fields so the flat list matches `recipe_struct`."""
    out: list[object] = []
    for v in values:
        if isinstance(v, list | tuple):
            out.extend(v)
        else:
            out.append(v)
    return out


@dataclass
class OutputRecipe:
    recipe_id: int
    names: list[str]
    types: list[str]
    packer: struct.Struct
    getters: list[Callable[[], object]]
    period_ticks: int
    next_tick: int = 0


@dataclass
class InputRecipe:
    recipe_id: int
    names: list[str]
    types: list[str]
    packer: struct.Struct


class RtdeSession:
    """Protocol state of one RTDE connection. `handle` answers one client message (returns the
    reply frames); `due_packages` builds the data packages due at a controller tick.

    `getter(name)` returns a function giving the current value of an output field (vectors as
    sequences); `write_inputs(names, values)` applies an input data package. Both are called
    with whatever lock the caller holds; the session itself has no threads and no socket.
    """

    def __init__(self, controller_version: tuple[int, int, int, int],
                 getter: Callable[[str], Callable[[], object]],
                 write_inputs: Callable[[Sequence[str], Sequence[object]], None],
                 log: Callable[[str], None], tick_hz: float = MAX_RATE_HZ) -> None:
        self.controller_version = controller_version
        self._getter, self._write, self._log = getter, write_inputs, log
        self.tick_hz = tick_hz
        self.protocol = 1
        self.outputs: list[OutputRecipe] = []
        self.inputs: list[InputRecipe] = []
        self.started = False

    def handle(self, msg_type: int, payload: bytes, tick: int) -> list[bytes]:
        if msg_type == MSG_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            ok = version in (1, 2)
            if ok:
                self.protocol = version
            return [frame(MSG_PROTOCOL_VERSION, struct.pack(">B", int(ok)))]
        if msg_type == MSG_CONTROLLER_VERSION:
            return [frame(MSG_CONTROLLER_VERSION, struct.pack(">IIII", *self.controller_version))]
        if msg_type == MSG_SETUP_OUTPUTS:
            return [self._setup_outputs(payload, tick)]
        if msg_type == MSG_SETUP_INPUTS:
            return [self._setup_inputs(payload)]
        if msg_type in (MSG_START, MSG_PAUSE):
            self.started = msg_type == MSG_START and bool(self.outputs)
            for r in self.outputs:
                r.next_tick = tick + 1
            ok = self.started or msg_type == MSG_PAUSE
            if self.started:
                outs = "; ".join(f"{len(r.names)} fields every {r.period_ticks} ticks" for r in self.outputs)
                self._log(f"RTDE: streaming started ({outs}; {len(self.inputs)} input recipes)")
            return [frame(msg_type, struct.pack(">B", int(ok)))]
        if msg_type == MSG_DATA:
            self._data(payload)
            return []
        self._log(f"RTDE: ignoring message type {msg_type} ({chr(msg_type) if 32 <= msg_type < 127 else '?'})")
        return [self.text(f"unknown message type {msg_type}", level=2)] if self.protocol == 2 else []

    def text(self, message: str, source: str = "emulator", level: int = 1) -> bytes:
        """A text message (protocol 2 layout: length-prefixed message and source, warning level)."""
        m, s = message.encode()[:255], source.encode()[:255]
        return frame(MSG_TEXT, struct.pack(">B", len(m)) + m + struct.pack(">B", len(s)) + s + struct.pack(">B", level))

    def due_packages(self, tick: int) -> list[bytes]:
        """Data packages of the output recipes due at `tick` (none while paused)."""
        if not self.started:
            return []
        out = []
        for r in self.outputs:
            if tick < r.next_tick:
                continue
            r.next_tick = max(r.next_tick + r.period_ticks, tick + 1)
            values = flatten([g() for g in r.getters])
            out.append(frame(MSG_DATA, struct.pack(">B", r.recipe_id) + r.packer.pack(*values)))
        return out

    def _setup_outputs(self, payload: bytes, tick: int) -> bytes:
        freq = 125.0
        if self.protocol == 2:
            (freq,) = struct.unpack(">d", payload[:8])
            payload = payload[8:]
        names = [n.strip() for n in payload.decode(errors="replace").split(",") if n.strip()]
        types = [OUTPUT_TYPES.get(n, "NOT_FOUND") for n in names]
        ok = bool(names) and "NOT_FOUND" not in types and 0 < freq <= MAX_RATE_HZ
        if not ok:
            missing = [n for n, t in zip(names, types, strict=True) if t == "NOT_FOUND"]
            self._log(f"RTDE output setup refused: frequency {freq} Hz, unknown fields {missing}")
            return frame(MSG_SETUP_OUTPUTS, struct.pack(">B", 0) + ",".join(types).encode())
        period = max(1, round(self.tick_hz / freq))
        recipe = OutputRecipe(len(self.outputs) + 1, names, types, recipe_struct(types),
                              [self._getter(n) for n in names], period, tick + 1)
        self.outputs.append(recipe)
        return frame(MSG_SETUP_OUTPUTS, struct.pack(">B", recipe.recipe_id) + ",".join(types).encode())

    def _setup_inputs(self, payload: bytes) -> bytes:
        names = [n.strip() for n in payload.decode(errors="replace").split(",") if n.strip()]
        types = [INPUT_TYPES.get(n, "NOT_FOUND") for n in names]
        if not names or "NOT_FOUND" in types:
            self._log(f"RTDE input setup refused: unknown fields {[n for n, t in zip(names, types, strict=True) if t == 'NOT_FOUND']}")
            return frame(MSG_SETUP_INPUTS, struct.pack(">B", 0) + ",".join(types).encode())
        recipe = InputRecipe(len(self.inputs) + 1, names, types, recipe_struct(types))
        self.inputs.append(recipe)
        return frame(MSG_SETUP_INPUTS, struct.pack(">B", recipe.recipe_id) + ",".join(types).encode())

    def _data(self, payload: bytes) -> None:
        if not payload:
            return
        rid = payload[0]
        if not 1 <= rid <= len(self.inputs):
            self._log(f"RTDE: data package for unknown input recipe {rid}")
            return
        r = self.inputs[rid - 1]
        if len(payload) - 1 != r.packer.size:
            self._log(f"RTDE: input recipe {rid} expects {r.packer.size} bytes, got {len(payload) - 1}")
            return
        flat = list(r.packer.unpack(payload[1:]))
        values: list[object] = []
        for t in r.types:
            width = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(t, 0)
            if width:
                values.append(tuple(flat[:width]))
                del flat[:width]
            else:
                values.append(flat.pop(0))
        self._write(r.names, values)
