"""The fibre DAQ's NMEA-style line protocol (``docs/devices.md``, "Fibre DAQ line protocol")::

    $F,<seq>,<t_us>,<r1>,<r2>,<r3>,<r4>*<XOR hex>\\r\\n     data, device -> host
    $RATE,<hz>   $ZERO   $ID   $START   $STOP              commands, host -> device
    $R,<CMD>,OK[,<data>...]   $R,<CMD>,ERR,<reason>         replies, device -> host
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

CHANNELS = ("SPS1", "SPS2", "SPS3", "S1")
"""Wire order of the four raw values: h1..h3 (surface profile sensors) and h4 (indenter)."""

SEQ_MOD = 1 << 32
"""The sample counter is 32-bit and wraps."""
CLOCK_MOD_US = 1 << 32
"""The device clock is a 32-bit microsecond counter (wraps every 71.6 min)."""
MAX_LINE = 256
"""Bytes without a line feed after which a reader discards its buffer as garbage."""


class SentenceError(ValueError):
    """A line that is not a valid sentence; ``kind`` is ``"resync"`` (no ``$``) or ``"corrupt"``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def checksum(body: bytes) -> int:
    """NMEA checksum: XOR of every byte between ``$`` and ``*`` (exclusive)."""
    cs = 0
    for b in body:
        cs ^= b
    return cs


def encode_sentence(body: str) -> bytes:
    """Frame ``body`` (e.g. ``"RATE,500"``) as ``$RATE,500*1B\\r\\n``."""
    raw = body.encode("ascii")
    return b"$" + raw + b"*%02X\r\n" % checksum(raw)


def decode_sentence(line: bytes, *, require_checksum: bool = True) -> tuple[list[str], bool]:
    """Split one received line (terminator stripped) into its comma-separated fields.

    Returns ``(fields, resynced)``: ``resynced`` is True when bytes before the last ``$``
    had to be discarded (garbage or the start of a truncated sentence). Raises
    :class:`SentenceError` (kind ``"resync"`` if there is no ``$`` at all, ``"corrupt"``
    for a missing (when required) or wrong checksum or non-ASCII bytes).
    """
    start = line.rfind(b"$")
    if start < 0:
        raise SentenceError("resync", f"no start marker in {line[:40]!r}")
    resynced = start > 0
    text = line[start + 1 :].rstrip(b"\r")
    star = text.rfind(b"*")
    if star < 0:
        if require_checksum:
            raise SentenceError("corrupt", f"no checksum in {line[:60]!r}")
        body = text
    else:
        body, cs_text = text[:star], text[star + 1 :]
        try:
            expected = int(cs_text, 16)
        except ValueError:
            raise SentenceError("corrupt", f"checksum {cs_text!r} is not hex in {line[:60]!r}") from None
        if len(cs_text) != 2 or checksum(body) != expected:
            raise SentenceError("corrupt", f"checksum mismatch in {line[:60]!r}")
    try:
        return body.decode("ascii").split(","), resynced
    except UnicodeDecodeError:
        raise SentenceError("corrupt", f"non-ASCII bytes in {line[:60]!r}") from None


@dataclass(frozen=True, slots=True)
class DataSentence:
    """One ``$F`` sample: counter, device clock (µs, wrapping) and the raw readings in wire order."""

    seq: int
    t_us: int
    raw: tuple[float, float, float, float]


def encode_data(seq: int, t_us: int, counts: Sequence[int]) -> bytes:
    """The ``$F`` line of one sample (integer ADC counts, as the device sends them)."""
    if len(counts) != len(CHANNELS):
        raise ValueError(f"a data sentence carries {len(CHANNELS)} readings {list(CHANNELS)}, got {len(counts)}")
    return encode_sentence(f"F,{seq},{t_us}," + ",".join(str(int(c)) for c in counts))


def parse_data(fields: Sequence[str]) -> DataSentence:
    """The sample in the fields of an ``F`` sentence (from :func:`decode_sentence`).

    Raises:
        ValueError: wrong field count, a non-number, or a value outside the wire ranges.
    """
    if len(fields) != 7 or fields[0] != "F":
        raise ValueError(f"{len(fields)} fields starting {fields[0]!r}, expected 7 starting 'F'" if fields else "empty")
    seq, t_us = int(fields[1]), int(fields[2])
    r = [float(v) for v in fields[3:7]]
    if not (0 <= seq < SEQ_MOD and 0 <= t_us < CLOCK_MOD_US and all(math.isfinite(v) for v in r)):
        raise ValueError("value out of range")
    return DataSentence(seq, t_us, (r[0], r[1], r[2], r[3]))


def encode_command(cmd: str, *args: str) -> bytes:
    """A host command such as ``$RATE,500*1B\\r\\n`` (with the checksum, which the device verifies)."""
    return encode_sentence(",".join((cmd, *args)))


@dataclass(frozen=True, slots=True)
class Reply:
    """A ``$R`` reply: the command it answers, whether it says OK (any other status is a refusal), and its data."""

    cmd: str
    ok: bool
    data: tuple[str, ...]


def encode_reply(cmd: str, ok: bool, *data: str) -> bytes:
    """``$R,<CMD>,OK[,data...]`` or ``$R,<CMD>,ERR,<reason>``."""
    return encode_sentence(",".join(("R", cmd, "OK" if ok else "ERR", *data)))


def parse_reply(fields: Sequence[str]) -> Reply | None:
    """The reply in the fields of an ``R`` sentence, or None if they are not one."""
    if len(fields) < 3 or fields[0] != "R":
        return None
    return Reply(fields[1], fields[2] == "OK", tuple(fields[3:]))
