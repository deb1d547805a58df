"""The fibre DAQ codec against byte strings written from docs/devices.md (not against the emulator).

Checksums here were worked out from the spec's rule (XOR of the bytes between ``$`` and ``*``, two upper-case
hex digits); the data line is the spec's own example.
"""

from __future__ import annotations

import pytest

from devices.fibre_daq import (
    DataSentence,
    Reply,
    SentenceError,
    checksum,
    decode_sentence,
    encode_command,
    encode_data,
    encode_reply,
    parse_data,
    parse_reply,
)

SPEC_DATA = b"$F,1006,4293967296,21000,21500,20500,33000*4A\r\n"
"""docs/devices.md, "Data (device -> host)"."""


def test_data_sentence_matches_the_spec_example() -> None:
    assert encode_data(1006, 4293967296, (21000, 21500, 20500, 33000)) == SPEC_DATA
    fields, resynced = decode_sentence(SPEC_DATA.rstrip(b"\r\n"))
    assert (fields, resynced) == (["F", "1006", "4293967296", "21000", "21500", "20500", "33000"], False)
    assert parse_data(fields) == DataSentence(1006, 4293967296, (21000.0, 21500.0, 20500.0, 33000.0))


def test_checksum_is_the_xor_between_dollar_and_star() -> None:
    # R^A^T^E^,^5^0^0 = 0x1B, worked by hand
    assert checksum(b"RATE,500") == 0x1B
    assert encode_command("RATE", "500") == b"$RATE,500*1B\r\n"
    assert encode_command("STOP") == b"$STOP*18\r\n"
    assert encode_command("START") == b"$START*40\r\n"


def test_replies_as_the_spec_writes_them() -> None:
    assert encode_reply("RATE", True, "500") == b"$R,RATE,OK,500*4D\r\n"
    assert encode_reply("?", False, "checksum") == b"$R,?,ERR,checksum*09\r\n"
    assert parse_reply(["R", "ZERO", "OK", "21000.0", "21500.0", "20500.0", "33000.0"]) == Reply(
        "ZERO", True, ("21000.0", "21500.0", "20500.0", "33000.0"))
    assert parse_reply(["R", "RATE", "ERR", "range 1..2000"]) == Reply("RATE", False, ("range 1..2000",))
    assert parse_reply(["R", "START", "OK"]) == Reply("START", True, ())
    assert parse_reply(["F", "1", "2", "3", "4", "5", "6"]) is None
    assert parse_reply(["R", "ID"]) is None


def test_commands_may_omit_the_checksum_but_a_present_one_is_checked() -> None:
    assert decode_sentence(b"$RATE,500", require_checksum=False) == (["RATE", "500"], False)
    assert decode_sentence(b"$RATE,500*1B", require_checksum=False) == (["RATE", "500"], False)
    with pytest.raises(SentenceError) as exc:
        decode_sentence(b"$RATE,500*1C", require_checksum=False)
    assert exc.value.kind == "corrupt"
    with pytest.raises(SentenceError) as exc:
        decode_sentence(b"$RATE,500")  # data from the device must carry one
    assert exc.value.kind == "corrupt"


def test_bytes_before_the_last_dollar_are_discarded() -> None:
    line = SPEC_DATA.rstrip(b"\r\n")
    fields = ["F", "1006", "4293967296", "21000", "21500", "20500", "33000"]
    assert decode_sentence(b"\x00\xff#noise" + line) == (fields, True)
    assert decode_sentence(b"$F,1005,42939" + line) == (fields, True)  # a truncated sentence glued to the next


@pytest.mark.parametrize(
    ("line", "kind"),
    [
        (b"F,1006,4293967296,21000,21500,20500,33000*4A", "resync"),  # no start marker
        (b"$F,1006,4293967296,21000,21500,20500,33000*4B", "corrupt"),  # one bit off
        (b"$F,1006,4293967296,21000,21500,20500,33000*A", "corrupt"),  # one digit
        (b"$F,1006,4293967296,21000,21500,20500,33000*04A", "corrupt"),  # three digits
        (b"$F,1006,4293967296,21000,21500,20500,33000*ZZ", "corrupt"),
        (b"$F,1006,4293967296,21000,21500,20500,33000", "corrupt"),  # no checksum
        (b"$F,\xe9*83", "corrupt"),  # checksum right, not ASCII
    ],
)
def test_malformed_lines_are_classified(line: bytes, kind: str) -> None:
    with pytest.raises(SentenceError) as exc:
        decode_sentence(line)
    assert exc.value.kind == kind


def test_wire_ranges_of_a_data_sentence() -> None:
    top = ["F", "4294967295", "4294967295", "0", "65535", "0.5", "1"]  # 2**32 - 1 for both counters
    assert parse_data(top) == DataSentence(4294967295, 4294967295, (0.0, 65535.0, 0.5, 1.0))
    for bad in (
        ["F", "4294967296", "0", "0", "0", "0", "0"],  # seq is 32-bit
        ["F", "0", "4294967296", "0", "0", "0", "0"],  # so is t_us
        ["F", "-1", "0", "0", "0", "0", "0"],
        ["F", "0", "0", "nan", "0", "0", "0"],
        ["F", "0", "0", "0", "0", "0"],  # three readings
        ["F", "0", "0", "0", "0", "0", "0", "0"],  # five
        ["F", "0", "0", "x", "0", "0", "0"],
    ):
        with pytest.raises(ValueError):
            parse_data(bad)
    with pytest.raises(ValueError, match="4 readings"):
        encode_data(0, 0, (1, 2, 3))
