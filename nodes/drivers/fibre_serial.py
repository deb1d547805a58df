"""Fibre DAQ driver on a serial line: the I/O of :class:`nodes.drivers.fibre.FibreDriver` for the real device.

The DAQ streams NMEA-style sentences; the wire protocol is specified in ``docs/devices.md`` and its
codec is :mod:`devices.fibre_daq` (shared with the emulator). This module is the I/O: a serial port,
an acquisition thread, resync and hot-replug.

Raw ADC counts become heights h1..h4 (mm, extension of each element from the probe face,
paper eqs. 1-3) through :mod:`models.fibre_calibration`; the device clock (32-bit
microseconds, wraps every 71.6 min) is mapped to the host clock by
:class:`models.clock_offset.ClockOffsetEstimator`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import termios
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path

import serial

from devices.fibre_daq import (
    CHANNELS,
    CLOCK_MOD_US,
    MAX_LINE,
    SEQ_MOD,
    Reply,
    SentenceError,
    decode_sentence,
    encode_command,
    parse_data,
    parse_reply,
)
from models.clock_offset import ClockOffsetEstimator
from models.fibre_calibration import FibreCalibration, load_calibration
from nodes.drivers.fibre import (
    FibreCommandError,
    FibreCounters,
    FibreError,
    FibreNotConnectedError,
    FibreSample,
    FibreStatus,
)
from nodes.drivers.host_clock import host_ns

log = logging.getLogger(__name__)

_IO_ERRORS = (serial.SerialException, OSError, termios.error)  # termios.error is not an OSError


class SerialFibreDriver:
    """The fibre DAQ on a serial port (pyserial), with resync, clock sync and hot-replug.

    A background thread owns the port: it reads and parses lines, stamps them with
    ``clock()`` on arrival, and when the port fails (unplugged adapter) closes it and
    retries ``port`` with exponential backoff (``backoff_s = (first, max)``), re-sending
    ``$START`` and the last requested rate when the device comes back. Meanwhile
    :meth:`read` returns [] and :meth:`status` reports ``connected=False``; the caller never
    re-creates the driver.

    Args:
        port: serial device path; prefer a stable link such as ``/dev/serial/by-id/...``.
        baudrate: line speed (ignored by USB-CDC devices and ptys).
        calibration: a :class:`FibreCalibration` or the path of a calibration YAML file.
        require_device: if True, :meth:`open` raises when the port cannot be opened at
            once; if False it keeps retrying in the background.
        command_timeout_s: how long a command waits for its ``$R`` reply.
        clock: host clock in ns (default the host's wall clock; inject the node's).
        clock_window_s: history used by the clock offset filter.
        max_queue: samples kept for :meth:`read`; older ones are discarded (``overruns``).
    """

    def __init__(
        self,
        port: str,
        baudrate: int,
        calibration: FibreCalibration | str | Path,
        *,
        require_device: bool = True,
        command_timeout_s: float = 0.5,
        backoff_s: tuple[float, float] = (0.05, 2.0),
        clock: Callable[[], int] = host_ns,
        clock_window_s: float = 10.0,
        max_queue: int = 20000,
    ) -> None:
        self._port = port
        self._baudrate = baudrate
        self._cal = calibration if isinstance(calibration, FibreCalibration) else load_calibration(calibration)
        self._require_device = require_device
        self._cmd_timeout = command_timeout_s
        self._backoff = backoff_s
        self._clock = clock
        self._est = ClockOffsetEstimator(window_s=clock_window_s)
        self._cond = threading.Condition()  # guards everything below except the port
        self._write_lock = threading.Lock()  # guards self._ser
        self._cmd_lock = threading.Lock()  # one command in flight
        self._ser: serial.Serial | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._samples: deque[FibreSample] = deque()
        self._max_queue = max_queue
        self._connected = False
        self._ever_connected = False
        self._last_error: str | None = None
        self._counts: dict[str, int] = {f: 0 for f in FibreCounters.__dataclass_fields__}
        self._offsets = [0.0] * len(CHANNELS)
        self._desired_rate: float | None = None
        self._confirmed_rate: float | None = None
        self._reply_wanted: str | None = None
        self._reply: Reply | None = None
        self._buf = bytearray()
        self._expected_seq: int | None = None
        self._last_t_us: int | None = None
        self._dev_us = 0

    # -- public API ------------------------------------------------------------------

    @property
    def calibration(self) -> FibreCalibration:
        """The calibration in use."""
        return self._cal

    def open(self) -> None:
        """Open the port and start the acquisition thread (no-op if already open).

        Raises:
            FibreNotConnectedError: the port cannot be opened and ``require_device`` is set.
        """
        if self._thread is not None:
            return
        self._stop.clear()
        if not self._try_connect() and self._require_device:
            raise FibreNotConnectedError(
                f"cannot open fibre DAQ at {self._port}: {self._last_error}; is it plugged in? "
                "(require_device=False waits for it instead)"
            )
        self._thread = threading.Thread(target=self._run, name=f"fibre:{self._port}", daemon=True)
        self._thread.start()

    def read(self, timeout_s: float) -> list[FibreSample]:
        """All samples received since the last call, waiting up to ``timeout_s`` for one."""
        with self._cond:
            self._cond.wait_for(lambda: bool(self._samples) or self._stop.is_set(), timeout_s)
            out = list(self._samples)
            self._samples.clear()
        return out

    def status(self) -> FibreStatus:
        """Connection state, counters and the current clock estimate."""
        with self._cond:
            return FibreStatus(
                connected=self._connected,
                last_error=self._last_error,
                counters=FibreCounters(**self._counts),
                clock_offset_ns=self._est.offset_ns(),
                clock_drift_ppm=self._est.drift_ppm,
                rate_hz=self._confirmed_rate,
                port=self._port,
            )

    def set_rate(self, hz: float) -> None:
        """Set the sampling rate in Hz (device range in docs/devices.md).

        Remembered and re-applied after every reconnect; while disconnected it is only
        remembered. Raises FibreCommandError if the device rejects it or does not answer.
        """
        if not (isinstance(hz, int | float) and math.isfinite(hz) and hz > 0):
            raise ValueError(f"rate must be a positive number of Hz, got {hz!r}")
        self._desired_rate = float(hz)
        with self._cond:
            if not self._connected:
                return
        reply = self._command("RATE", f"{hz:g}")
        with self._cond:
            self._confirmed_rate = float(reply[0]) if reply else float(hz)

    def zero(self) -> None:
        """Tare: from now on the current pose reads each channel's ``zero_mm``.

        The device answers ``$ZERO`` with its mean raw reading; the per-channel offset is
        ``zero_mm - poly(raw_mean)``. Raises FibreNotConnectedError while disconnected.
        """
        reply = self._command("ZERO")
        try:
            means = [float(v) for v in reply]
        except ValueError:
            raise FibreCommandError(f"{self._port}: malformed $ZERO reply {reply!r}") from None
        if len(means) != len(CHANNELS):
            raise FibreCommandError(f"{self._port}: $ZERO reply has {len(means)} values, expected {len(CHANNELS)}")
        with self._cond:
            self._offsets = [ch.zero_mm - ch.height_mm(m) for ch, m in zip(self._cal.channels, means, strict=True)]

    def identify(self) -> str:
        """The device's identification string (``$ID`` reply fields joined by commas)."""
        return ",".join(self._command("ID"))

    def close(self) -> None:
        """Stop streaming (best effort), stop the thread and close the port (idempotent)."""
        self._stop.set()
        with self._write_lock:
            if self._ser is not None:
                with contextlib.suppress(Exception):
                    self._ser.write(encode_command("STOP"))
                with contextlib.suppress(Exception):
                    self._ser.cancel_read()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._close_port()
        with self._cond:
            self._connected = False
            self._cond.notify_all()

    def __enter__(self) -> SerialFibreDriver:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- commands --------------------------------------------------------------------

    def _command(self, cmd: str, *args: str) -> list[str]:
        with self._cmd_lock:
            with self._cond:
                if not self._connected:
                    raise FibreNotConnectedError(f"{self._port}: cannot send ${cmd}: DAQ not connected")
                self._reply_wanted, self._reply = cmd, None
            try:
                self._write(encode_command(cmd, *args))
                with self._cond:
                    self._cond.wait_for(lambda: self._reply is not None or not self._connected, self._cmd_timeout)
                    reply = self._reply
            finally:
                with self._cond:
                    self._reply_wanted = None
        if reply is None:
            raise FibreCommandError(f"{self._port}: no reply to ${cmd} within {self._cmd_timeout} s")
        if not reply.ok:
            raise FibreCommandError(f"{self._port}: device rejected ${cmd}: {','.join(reply.data) or 'no reason given'}")
        return list(reply.data)

    def _write(self, data: bytes) -> None:
        with self._write_lock:
            if self._ser is None:
                raise FibreNotConnectedError(f"{self._port}: DAQ not connected")
            try:
                self._ser.write(data)
            except _IO_ERRORS as exc:
                raise FibreNotConnectedError(f"{self._port}: write failed: {exc}") from None

    # -- acquisition thread ----------------------------------------------------------

    def _try_connect(self) -> bool:
        try:
            ser = serial.Serial(self._port, self._baudrate, timeout=0.05, write_timeout=0.5)
            ser.reset_input_buffer()
        except (*_IO_ERRORS, ValueError) as exc:
            with self._cond:
                self._last_error = f"open {self._port}: {exc}"
            return False
        with self._write_lock:
            self._ser = ser
        self._buf.clear()
        # A (re)connected device may have rebooted, and a short uptime can look continuous;
        # so sequence, clock unwrap and offset estimate restart with every connection.
        self._last_t_us = self._expected_seq = None
        with self._cond:
            self._est.reset()
            if self._ever_connected:
                self._counts["reconnects"] += 1
                log.info("fibre DAQ %s reconnected", self._port)
            self._ever_connected = True
            self._connected = True
            self._confirmed_rate = None
        with contextlib.suppress(FibreError):
            self._write(encode_command("START"))
            if self._desired_rate is not None:
                self._write(encode_command("RATE", f"{self._desired_rate:g}"))
        return True

    def _close_port(self) -> None:
        with self._write_lock:
            ser, self._ser = self._ser, None
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()

    def _run(self) -> None:
        backoff = self._backoff[0]
        while not self._stop.is_set():
            ser = self._ser
            if ser is None:
                if self._try_connect():
                    backoff = self._backoff[0]
                else:
                    self._stop.wait(backoff)
                    backoff = min(backoff * 2, self._backoff[1])
                continue
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (*_IO_ERRORS, TypeError) as exc:
                if self._stop.is_set():
                    break
                self._close_port()
                with self._cond:
                    self._connected = False
                    self._last_error = f"{self._port}: connection lost: {exc}"
                    self._cond.notify_all()
                log.warning("fibre DAQ %s lost: %s; reconnecting", self._port, exc)
                continue
            if data:
                self._feed(data, self._clock())

    def _feed(self, data: bytes, host_ns: int) -> None:
        buf = self._buf
        buf += data
        while True:
            nl = buf.find(b"\n")
            if nl < 0:
                if len(buf) > MAX_LINE:  # no terminator in sight: garbage
                    buf.clear()
                    self._bump("resyncs")
                return
            line = bytes(buf[:nl]).strip(b"\r")
            del buf[: nl + 1]
            if line:
                self._handle_line(line, host_ns)

    def _bump(self, counter: str, error: str | None = None) -> None:
        with self._cond:
            self._counts[counter] += 1
            if error is not None:
                self._last_error = error

    def _handle_line(self, line: bytes, host_ns: int) -> None:
        try:
            fields, resynced = decode_sentence(line)
        except SentenceError as exc:
            self._bump("resyncs" if exc.kind == "resync" else "corrupt", f"{self._port}: {exc}")
            return
        if resynced:
            self._bump("resyncs")
        if fields[0] == "F":
            self._handle_data(fields, host_ns)
        elif (reply := parse_reply(fields)) is not None:
            with self._cond:
                if reply.cmd == "RATE" and reply.ok and reply.data:
                    with contextlib.suppress(ValueError):
                        self._confirmed_rate = float(reply.data[0])
                if reply.cmd == self._reply_wanted:
                    self._reply = reply
                    self._cond.notify_all()
        else:
            log.debug("fibre DAQ %s: ignoring sentence %r", self._port, fields[0])

    def _handle_data(self, fields: list[str], host_ns: int) -> None:
        try:
            data = parse_data(fields)
        except ValueError as exc:
            self._bump("corrupt", f"{self._port}: malformed data sentence ({exc}): {','.join(fields)[:60]}")
            return
        seq, t_us, raw = data.seq, data.t_us, data.raw
        restarted = False
        if self._last_t_us is None:
            self._dev_us = t_us
        else:
            dt = (t_us - self._last_t_us) % CLOCK_MOD_US
            restarted = dt >= CLOCK_MOD_US // 2
            if self._expected_seq is not None and (seq - self._expected_seq) % SEQ_MOD >= SEQ_MOD // 2:
                restarted = True
            if restarted:  # device rebooted: new time base, no gap to count
                self._dev_us = t_us
                log.info("fibre DAQ %s restarted (seq %d, t %d us)", self._port, seq, t_us)
            else:
                self._dev_us += dt
        gap = 0 if restarted or self._expected_seq is None else (seq - self._expected_seq) % SEQ_MOD
        self._last_t_us = t_us
        self._expected_seq = (seq + 1) % SEQ_MOD
        dev_ns = self._dev_us * 1000
        with self._cond:
            if restarted:
                self._est.reset()
            self._est.update(dev_ns, host_ns)
            stamp = self._est.to_host_ns(dev_ns)
            heights = self._cal.heights_mm(raw, self._offsets)
            sample = FibreSample(host_ns, dev_ns, seq, raw, (heights[0], heights[1], heights[2], heights[3]), host_ns if stamp is None else stamp)
            c = self._counts
            c["samples"] += 1
            c["dropped"] += gap
            if any(not ch.raw_range[0] <= v <= ch.raw_range[1] for ch, v in zip(self._cal.channels, raw, strict=True)):
                c["out_of_range"] += 1
            if len(self._samples) >= self._max_queue:
                self._samples.popleft()
                c["overruns"] += 1
            self._samples.append(sample)
            self._cond.notify_all()
