"""State fields are Literal types: the wire is unchanged (a msgpack str), and a value outside the set is refused."""

from __future__ import annotations

import msgspec
import pytest

from messages import DeviceStatus, PressureState, ScanStatus
from messages.robot import PlanWaypoint


class _OldScanStatus(msgspec.Struct, kw_only=True):
    """ScanStatus as it was declared before (``state: str``)."""

    stamp_ns: int
    state: str
    line: int
    lines: int
    progress: float
    eta_s: float
    message: str = ""


def test_a_literal_state_is_a_plain_msgpack_string_both_ways() -> None:
    new = ScanStatus(stamp_ns=1, state="scanning", line=2, lines=3, progress=0.5, eta_s=4.0)
    wire = msgspec.msgpack.encode(new)
    assert msgspec.msgpack.decode(wire)["state"] == "scanning"
    assert msgspec.msgpack.decode(wire, type=_OldScanStatus).state == "scanning"
    old = _OldScanStatus(stamp_ns=1, state="done", line=3, lines=3, progress=1.0, eta_s=0.0)
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(old), type=ScanStatus).state == "done"


@pytest.mark.parametrize(("typ", "field", "good", "doc"), [
    (ScanStatus, "state", "paused", {"stamp_ns": 0, "line": 0, "lines": 1, "progress": 0.0, "eta_s": 0.0}),
    (DeviceStatus, "state", "reconnecting", {"stamp_ns": 0, "device": "camera", "connected": False}),
    (PressureState, "mode", "vent", {"stamp_ns": 0, "setpoint_kpa": 0.0, "measured_kpa": 0.0, "force_n": 0.0,
                                     "max_kpa": 60.0}),
    (PlanWaypoint, "kind", "press", {"x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0, "speed_mm_s": 1.0, "line": 0}),
])
def test_a_value_outside_the_set_is_refused(typ: type, field: str, good: str, doc: dict[str, object]) -> None:
    assert getattr(msgspec.msgpack.decode(msgspec.msgpack.encode({**doc, field: good}), type=typ), field) == good
    with pytest.raises(msgspec.ValidationError, match=rf"Invalid enum value 'scaning' - at `\$.{field}`"):
        msgspec.msgpack.decode(msgspec.msgpack.encode({**doc, field: "scaning"}), type=typ)
