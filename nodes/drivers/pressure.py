"""Electronic pressure controller driver: Alicat PC-series over its serial ASCII protocol.

The supply pressure ``Ps`` of the air-float probe sets the indentation force (paper eq. 4,
``F = 7.59 Ps - 2.34``), so the controller is a safety item: the driver enforces its own
hard maximum (``max_kpa``) whatever the node asks for. The protocol and its quirks are in
``docs/devices.md`` and its codec is :mod:`devices.alicat` (shared with the emulator).

Polling is synchronous (no thread; use one driver from one thread): each call writes, then waits up to ``timeout_s`` for
the reply. When the port fails (adapter unplugged) the driver closes it and re-opens it on
a later call, with exponential backoff, without the caller re-creating anything.
"""

from __future__ import annotations

import contextlib
import logging
import math
import termios
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import serial

from devices.alicat import (
    KPA_PER_UNIT,
    TERMINATOR,
    UnknownCommandReply,
    encode_command,
    parse_frame,
    parse_text_reply,
    setpoint_command,
)
from nodes.drivers.host_clock import host_ns

_IO_ERRORS = (serial.SerialException, OSError, termios.error)  # termios.error is not an OSError

log = logging.getLogger(__name__)

FLAG_CLAMPED = "CLAMPED"  # driver flag: the requested set-point exceeded max_kpa and was clamped
FLAG_OVER_MAX = "OVER_MAX"  # driver flag: measured pressure above max_kpa (+ tolerance)
FLAG_SETPOINT_MISMATCH = "SETPOINT_MISMATCH"  # driver flag: device echoed another set-point


class PressureError(Exception):
    """Base class of pressure controller driver errors."""


class PressureNotConnectedError(PressureError):
    """The controller's port is not open (unplugged, or never found)."""


class PressureTimeoutError(PressureError):
    """The controller did not answer within the timeout."""


class PressureCommandError(PressureError):
    """The controller answered ``?`` (command not understood / not supported) or garbage."""


@dataclass(frozen=True, slots=True)
class PressureReading:
    """One data frame from the controller.

    Attributes:
        stamp_ns: host clock (ns) halfway between request and reply.
        setpoint_kpa: set-point the device reports (kPa).
        measured_kpa: measured pressure (kPa).
        flags: device status codes (``HLD``, ``EXH``, ``OPL``, ...) plus driver flags
            ``CLAMPED``, ``OVER_MAX``, ``SETPOINT_MISMATCH``.
    """

    stamp_ns: int
    setpoint_kpa: float
    measured_kpa: float
    flags: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class PressureCounters:
    """Event counters since construction; none of these is fatal."""

    polls: int = 0  # data frames received
    timeouts: int = 0  # commands that got no (complete) reply in time
    unknown: int = 0  # '?' replies
    corrupt: int = 0  # replies that are not a data frame of our unit
    reconnects: int = 0  # successful re-openings after losing the port
    clamped: int = 0  # set-points clamped to max_kpa


@dataclass(frozen=True, slots=True)
class PressureStatus:
    """Snapshot of the driver state."""

    connected: bool
    last_error: str | None  # most recent problem; kept after recovery
    counters: PressureCounters
    max_kpa: float
    commanded_kpa: float | None  # last set-point sent (after clamping)
    last_reading: PressureReading | None
    port: str = ""


@runtime_checkable
class PressureDriver(Protocol):
    """What the pressure regulator node needs from a backend (serial device or simulation)."""

    def open(self) -> None:
        """Connect to the controller."""

    def set_setpoint(self, kpa: float) -> PressureReading:
        """Command a set-point (kPa), clamped to ``[0, max_kpa]``; returns the device's frame."""

    def hold(self) -> PressureReading:
        """Freeze the valve at its current position."""

    def vent(self) -> PressureReading:
        """Cancel any hold and command 0 kPa (the probe exhausts through its tip)."""

    def read(self, timeout_s: float) -> PressureReading | None:
        """Poll one reading; None on timeout or while disconnected (never raises for I/O)."""

    def status(self) -> PressureStatus:
        """Connection state and counters."""

    def close(self) -> None:
        """Release the port (idempotent)."""


class AlicatPressureDriver:
    """An Alicat pressure controller on a serial port, polled in ASCII.

    Args:
        port: serial device (prefer a ``/dev/serial/by-id/...`` link).
        unit_id: the device's unit id letter (factory default ``A``).
        max_kpa: hard maximum set-point in kPa, enforced here whatever the caller asks.
        baudrate: line speed (Alicat factory default 19200 on older, 38400 on newer units).
        device_unit: the pressure unit the device is configured for (key of KPA_PER_UNIT).
        timeout_s: reply timeout for commands.
        backoff_s: (first, max) delay between re-open attempts after losing the port.
        setpoint_space: send ``AS 30.0`` (newer primers) instead of ``AS30.0``.
        require_device: :meth:`open` raises if the port cannot be opened at once.
        clock: host clock in ns for reading stamps.
    """

    def __init__(
        self,
        port: str,
        unit_id: str,
        max_kpa: float,
        baudrate: int = 19200,
        *,
        device_unit: str = "kPa",
        timeout_s: float = 0.2,
        backoff_s: tuple[float, float] = (0.05, 2.0),
        setpoint_space: bool = False,
        require_device: bool = True,
        over_max_tolerance_kpa: float = 0.5,
        clock: Callable[[], int] = host_ns,
    ) -> None:
        if not (len(unit_id) == 1 and "A" <= unit_id.upper() <= "Z"):
            raise ValueError(f"unit_id must be one letter A..Z, got {unit_id!r}")
        if not (isinstance(max_kpa, int | float) and math.isfinite(max_kpa) and max_kpa > 0):
            raise ValueError(f"max_kpa must be a positive number of kPa, got {max_kpa!r}")
        if device_unit not in KPA_PER_UNIT:
            raise ValueError(f"device_unit must be one of {sorted(KPA_PER_UNIT)}, got {device_unit!r}")
        self._port = port
        self._uid = unit_id.upper()
        self._max = float(max_kpa)
        self._baud = baudrate
        self._k = KPA_PER_UNIT[device_unit]
        self._timeout = timeout_s
        self._backoff = backoff_s
        self._space = setpoint_space
        self._require = require_device
        self._over_tol = over_max_tolerance_kpa
        self._clock = clock
        self._ser: serial.Serial | None = None
        self._opened = False
        self._ever_connected = False
        self._next_retry = 0
        self._delay = backoff_s[0]
        self._last_error: str | None = None
        self._counts: dict[str, int] = {f: 0 for f in PressureCounters.__dataclass_fields__}
        self._commanded: float | None = None
        self._last: PressureReading | None = None

    # -- connection ------------------------------------------------------------------

    def open(self) -> None:
        """Open the port. Raises PressureNotConnectedError if it cannot (and require_device)."""
        self._opened = True
        if self._ser is None and not self._connect() and self._require:
            raise PressureNotConnectedError(
                f"cannot open pressure controller at {self._port}: {self._last_error}; is it plugged in? "
                "(require_device=False retries on later calls instead)"
            )

    def close(self) -> None:
        """Close the port (idempotent). The set-point on the device is left as it is."""
        self._opened = False
        self._drop_port()

    def __enter__(self) -> AlicatPressureDriver:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _connect(self) -> bool:
        try:
            self._ser = serial.Serial(self._port, self._baud, timeout=self._timeout, write_timeout=self._timeout)
            self._ser.reset_input_buffer()
        except (*_IO_ERRORS, ValueError) as exc:
            self._ser = None
            self._last_error = f"open {self._port}: {exc}"
            self._next_retry = self._clock() + int(self._delay * 1e9)
            self._delay = min(self._delay * 2, self._backoff[1])
            return False
        if self._ever_connected:
            self._counts["reconnects"] += 1
            log.info("pressure controller %s reconnected", self._port)
        self._ever_connected = True
        self._delay = self._backoff[0]
        return True

    def _drop_port(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()

    def _lost(self, exc: BaseException) -> PressureNotConnectedError:
        self._drop_port()
        self._last_error = f"{self._port}: connection lost: {exc}"
        self._next_retry = self._clock() + int(self._delay * 1e9)
        log.warning("pressure controller %s lost: %s", self._port, exc)
        return PressureNotConnectedError(self._last_error)

    def _ensure_port(self) -> serial.Serial:
        if not self._opened:
            raise PressureNotConnectedError(f"{self._port}: driver not open (call open() first)")
        if self._ser is None and self._clock() >= self._next_retry:
            self._connect()
        if self._ser is None:
            raise PressureNotConnectedError(f"{self._port}: not connected ({self._last_error})")
        return self._ser

    # -- transactions ----------------------------------------------------------------

    def _transact(self, command: str, timeout_s: float | None = None) -> tuple[str, int]:
        """Send ``<uid><command>\\r``; return (reply line, stamp_ns)."""
        ser = self._ensure_port()
        timeout = self._timeout if timeout_s is None else timeout_s
        try:
            ser.reset_input_buffer()  # a late reply to an earlier, timed-out command
            t0 = self._clock()
            ser.write(encode_command(self._uid, command))
            ser.timeout = timeout
            raw = ser.read_until(TERMINATOR)
            t1 = self._clock()
        except _IO_ERRORS as exc:
            raise self._lost(exc) from None
        if not raw.endswith(TERMINATOR):
            self._counts["timeouts"] += 1
            self._last_error = f"{self._port}: no reply to {self._uid}{command!s} within {timeout} s" + (
                f" (partial {raw[:40]!r})" if raw else ""
            )
            raise PressureTimeoutError(self._last_error)
        return raw[:-1].decode("ascii", "replace").strip("\x00\n "), (t0 + t1) // 2

    def _frame(self, command: str, timeout_s: float | None = None, extra: frozenset[str] = frozenset()) -> PressureReading:
        line, stamp = self._transact(command, timeout_s)
        try:
            measured, setpoint, codes = parse_frame(line, self._uid, self._k)
        except UnknownCommandReply:
            self._counts["unknown"] += 1
            self._last_error = f"{self._port}: device answered '?' to {self._uid}{command}"
            raise PressureCommandError(self._last_error + " (not supported by this model/firmware?)") from None
        except ValueError as exc:
            self._counts["corrupt"] += 1
            self._last_error = f"{self._port}: reply to {self._uid}{command}: {exc}"
            raise PressureCommandError(self._last_error) from None
        flags = set(codes | extra)
        if measured > self._max + self._over_tol:
            flags.add(FLAG_OVER_MAX)
        reading = PressureReading(stamp, setpoint, measured, frozenset(flags))
        self._counts["polls"] += 1
        self._last = reading
        return reading

    # -- public API ------------------------------------------------------------------

    def read(self, timeout_s: float) -> PressureReading | None:
        """Poll the data frame; None on timeout, ``?``, garbage or while disconnected."""
        try:
            return self._frame("", timeout_s)
        except PressureError:
            return None

    def set_setpoint(self, kpa: float) -> PressureReading:
        """Command ``kpa`` (clamped to ``[0, max_kpa]``; a clamp is counted, logged and
        flagged ``CLAMPED`` on the returned reading).

        Raises:
            ValueError: ``kpa`` is not a finite number.
            PressureError: not connected, no reply, or ``?``.
        """
        if isinstance(kpa, bool) or not isinstance(kpa, int | float) or not math.isfinite(kpa):
            raise ValueError(f"set-point must be a finite number of kPa, got {kpa!r}")
        target = min(max(float(kpa), 0.0), self._max)
        extra: frozenset[str] = frozenset()
        if target != kpa:
            extra = frozenset({FLAG_CLAMPED})
            if kpa > self._max:
                self._counts["clamped"] += 1
                self._last_error = f"set-point {kpa:g} kPa above the hard maximum {self._max:g} kPa: clamped"
                log.warning("%s: %s", self._port, self._last_error)
        self._commanded = target
        reading = self._frame(setpoint_command(target / self._k, space=self._space), extra=extra)
        if abs(reading.setpoint_kpa - target) > max(0.01 * self._max, 0.05):
            self._last_error = f"{self._port}: device reports set-point {reading.setpoint_kpa:g} kPa after commanding {target:g} kPa"
            reading = PressureReading(reading.stamp_ns, reading.setpoint_kpa, reading.measured_kpa, reading.flags | {FLAG_SETPOINT_MISMATCH})
        return reading

    def hold(self) -> PressureReading:
        """Hold the valve at its current position (``AHP``); the frame then shows ``HLD``."""
        return self._frame("HP")

    def cancel_hold(self) -> PressureReading:
        """Resume closed-loop control (``AC``)."""
        return self._frame("C")

    def vent(self) -> PressureReading:
        """Cancel any hold, then command 0 kPa. Tries the set-point even if ``AC`` fails."""
        with contextlib.suppress(PressureTimeoutError, PressureCommandError):
            self.cancel_hold()
        return self.set_setpoint(0.0)

    def identify(self) -> str:
        """Firmware identification (``AVE`` reply), e.g. ``10v05.0-R24``."""
        line, _ = self._transact("VE")
        try:
            return parse_text_reply(line, self._uid)
        except UnknownCommandReply:
            self._counts["unknown"] += 1
            raise PressureCommandError(f"{self._port}: device answered '?' to {self._uid}VE") from None

    def status(self) -> PressureStatus:
        """Connection state and counters."""
        return PressureStatus(
            connected=self._ser is not None,
            last_error=self._last_error,
            counters=PressureCounters(**self._counts),
            max_kpa=self._max,
            commanded_kpa=self._commanded,
            last_reading=self._last,
            port=self._port,
        )
