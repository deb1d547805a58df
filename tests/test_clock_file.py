"""emulators.clock_file: the clock a graph publishes for the emulators that follow it."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from emulators.clock_file import ClockReader, ClockWriter


def test_a_follower_reads_the_last_time_written_none_before_and_after_release(tmp_path: Path) -> None:
    writer = ClockWriter(tmp_path / "clock")
    reader = ClockReader(writer.path)
    try:
        assert reader.read() is None  # nothing written: the follower keeps to the wall clock
        writer.write(1_000)
        writer.write(2**62)
        assert reader.read() == 2**62
        with pytest.raises(ValueError, match="never decrease"):
            writer.write(5)
        writer.release()
        assert reader.read() is None
        writer.write(7)  # released: the clock may start again anywhere
        assert reader.read() == 7
    finally:
        reader.close()
        writer.close()
    assert ClockReader(writer.path).read() is None  # a closed writer releases its followers


def test_a_half_written_time_is_never_read_and_a_file_that_is_no_clock_is_refused(tmp_path: Path) -> None:
    torn = tmp_path / "torn"
    torn.write_bytes(struct.pack("<qq", 5_000, ~4_000))  # the time of one write, the check of another
    with pytest.raises(RuntimeError, match="never read consistently"):
        ClockReader(torn).read()
    short = tmp_path / "short"
    short.write_bytes(b"\x01\x02")
    with pytest.raises(ValueError, match="not a clock file"):
        ClockReader(short)
