"""The Alicat ASCII codec against strings written from docs/devices.md (not against the emulator)."""

from __future__ import annotations

import pytest

from devices.alicat import (
    KPA_PER_UNIT,
    UnknownCommandReply,
    decode_command,
    encode_command,
    encode_frame,
    encode_text_reply,
    parse_frame,
    parse_text_reply,
    setpoint_command,
)


def test_commands_as_the_spec_table_writes_them() -> None:
    assert encode_command("A") == b"A\r"  # poll
    assert encode_command("A", setpoint_command(30.0)) == b"AS30.000\r"
    assert encode_command("A", setpoint_command(30.0, space=True)) == b"AS 30.000\r"  # newer primers (quirk 3)
    assert encode_command("A", "HP") == b"AHP\r"
    assert encode_command("A", "C") == b"AC\r"
    assert encode_command("B", "VE") == b"BVE\r"


def test_data_frames_of_a_pressure_controller() -> None:
    assert parse_frame("A +030.00 +030.00", "A") == (30.0, 30.0, frozenset())
    assert parse_frame("A +000.13 +012.50", "A") == (0.13, 12.5, frozenset())
    # extra numeric columns are ignored; status codes trail (quirk 8)
    assert parse_frame("A +030.00 +029.50 +055.1 HLD OPL", "A") == (30.0, 29.5, frozenset({"HLD", "OPL"}))
    assert parse_frame("A -000.20 +000.00 exh", "A") == (-0.2, 0.0, frozenset({"EXH"}))
    measured, setpoint, _ = parse_frame("A +004.35 +004.35", "A", KPA_PER_UNIT["psi"])
    assert measured == pytest.approx(29.992, abs=1e-3) and setpoint == measured  # 4.35 psi = 29.99 kPa
    assert KPA_PER_UNIT["bar"] == 100.0 and KPA_PER_UNIT["mbar"] == 0.1 and KPA_PER_UNIT["Pa"] == 1e-3


def test_frames_that_are_not_ours_are_refused() -> None:
    for line in ("?", "A ?"):
        with pytest.raises(UnknownCommandReply):
            parse_frame(line, "A")
    with pytest.raises(ValueError, match="unit A"):
        parse_frame("B +030.00 +030.00", "A")  # another device on the bus
    with pytest.raises(ValueError, match="unit A"):
        parse_frame("A +030.00", "A")
    with pytest.raises(ValueError, match="not numbers"):
        parse_frame("A +03x.00 +030.00", "A")


def test_frames_the_device_side_writes() -> None:
    assert encode_frame("A", 30.0, 30.0) == b"A +030.00 +030.00\r"
    assert encode_frame("A", 0.13, 12.5, ["HLD"]) == b"A +000.13 +012.50 HLD\r"
    assert encode_frame("A", -0.2, 0.0, ["EXH", "OPL"]) == b"A -000.20 +000.00 EXH OPL\r"


def test_firmware_reply() -> None:
    assert encode_text_reply("A", "10v05.0-R24") == b"A   10v05.0-R24\r"
    assert parse_text_reply("A   10v05.0-R24", "A") == "10v05.0-R24"
    assert parse_text_reply("10v05.0-R24", "A") == "10v05.0-R24"  # firmware without the unit id
    with pytest.raises(UnknownCommandReply):
        parse_text_reply("?", "A")


def test_device_side_command_decoding() -> None:
    assert decode_command(b"as30.0") == ("A", "S30.0")  # case-insensitive
    assert decode_command(b"AS 30.0") == ("A", "S 30.0")
    assert decode_command(b"A$$H") == ("A", "H")  # legacy prefix (quirk 6)
    assert decode_command(b"A$$PC") == ("A", "PC")
    assert decode_command(b"*") == ("*", "")  # broadcast poll
    assert decode_command(b"  \n") is None
