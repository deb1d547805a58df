"""Alicat serial ASCII (``docs/devices.md``, "Alicat pressure controller"): every command is
``<unit id><command>\\r``; the device answers one line ending in ``\\r`` only::

    A          -> A +030.00 +030.00            poll: unit id, pressure, set-point [, codes]
    AS30.000   -> data frame                   new set-point (device units)
    AHP / AC   -> data frame (+ HLD / - HLD)   hold valve at current position / cancel hold
    AVE        -> A   10v05.0-R24              firmware
    A??        -> ?                            unknown command
"""

from __future__ import annotations

from collections.abc import Sequence

KPA_PER_UNIT = {"kPa": 1.0, "Pa": 1e-3, "bar": 100.0, "mbar": 0.1, "psi": 6.894757293168361}
"""Device engineering units (the device's configured pressure unit) -> kPa per unit."""

TERMINATOR = b"\r"
"""Commands and replies both end in CR only."""
UNKNOWN = "?"
"""The whole reply to a command the device does not understand."""
LEGACY_PREFIX = "$$"
"""Older firmware syntax some clients put before a command (``A$$H``)."""


class UnknownCommandReply(ValueError):
    """The device answered ``?``: command not understood, or not supported by this model/firmware."""


def encode_command(unit_id: str, command: str = "") -> bytes:
    """``<unit id><command>\\r`` (an empty command polls the data frame)."""
    return f"{unit_id}{command}".encode("ascii") + TERMINATOR


def setpoint_command(value: float, *, space: bool = False) -> str:
    """The set-point command for ``value`` in device units: ``S30.000`` (``S 30.000`` for newer primers)."""
    return f"S{' ' if space else ''}{value:.3f}"


def decode_command(line: bytes) -> tuple[str, str] | None:
    """Device side: ``(unit id, command)`` of one received line, both upper case, the legacy ``$$`` removed;
    None for an empty line."""
    text = line.decode("ascii", "replace").strip()
    if not text:
        return None
    return text[0].upper(), text[1:].strip().upper().removeprefix(LEGACY_PREFIX)


def encode_frame(unit_id: str, pressure: float, setpoint: float, codes: Sequence[str] = ()) -> bytes:
    """A pressure controller's data frame ``A +030.00 +029.50 HLD\\r`` (values in device units)."""
    return " ".join([unit_id, f"{pressure:+07.2f}", f"{setpoint:+07.2f}", *codes]).encode("ascii") + TERMINATOR


def parse_frame(line: str, unit_id: str, kpa_per_unit: float = 1.0) -> tuple[float, float, frozenset[str]]:
    """Parse a data frame ``"A +030.00 +029.50 [extra numbers] [codes]"`` (terminator stripped).

    Returns ``(measured_kpa, setpoint_kpa, device codes)``. Extra numeric columns (valve
    drive, temperature on some models) are ignored.

    Raises:
        UnknownCommandReply: the line is ``?``.
        ValueError: anything that is not a data frame of ``unit_id``.
    """
    tokens = line.split()
    if tokens in ([UNKNOWN], [unit_id, UNKNOWN]):
        raise UnknownCommandReply("device answered '?'")
    if len(tokens) < 3 or tokens[0].upper() != unit_id:
        raise ValueError(f"not a data frame of unit {unit_id}: {line[:60]!r}")
    try:
        measured, setpoint = float(tokens[1]), float(tokens[2])
    except ValueError:
        raise ValueError(f"pressure/set-point columns are not numbers: {line[:60]!r}") from None
    codes = []
    for tok in tokens[3:]:
        try:
            float(tok)
        except ValueError:
            codes.append(tok.upper())
    return measured * kpa_per_unit, setpoint * kpa_per_unit, frozenset(codes)


def encode_text_reply(unit_id: str, text: str) -> bytes:
    """A non-frame reply such as the firmware line ``A   10v05.0-R24\\r`` (unit id, three spaces, text)."""
    return f"{unit_id}   {text}".encode("ascii") + TERMINATOR


def parse_text_reply(line: str, unit_id: str) -> str:
    """The text of a non-frame reply, without the unit id in front (some firmware omits it).

    Raises:
        UnknownCommandReply: the line is ``?``.
    """
    if line in (UNKNOWN, f"{unit_id} {UNKNOWN}"):
        raise UnknownCommandReply("device answered '?'")
    return line.split(maxsplit=1)[1] if line.upper().startswith(unit_id + " ") else line
