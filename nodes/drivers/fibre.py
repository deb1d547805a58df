"""Fibre-optic displacement DAQ driver: four Keyence FS-N10 channels over a serial line.

The DAQ (a microcontroller sampling the four amplifier outputs SPS1, SPS2, SPS3 and the
indenter S1) streams NMEA-style sentences; the wire protocol is specified in
``docs/devices.md`` and implemented by ``emulators/fibre_daq.py``. In short::

    $F,<seq>,<t_us>,<r1>,<r2>,<r3>,<r4>*<XOR hex>\\r\\n     data, device -> host
    $RATE,<hz>   $ZERO   $ID   $START   $STOP              commands, host -> device
    $R,<CMD>,OK[,<data>...]   $R,<CMD>,ERR,<reason>         replies, device -> host

Raw ADC counts become heights h1..h4 (mm, extension of each element from the probe face,
paper eqs. 1-3) through per-channel calibration polynomials (paper Fig. 3) loaded from
YAML by :func:`load_calibration`. The device clock (32-bit microseconds, wraps every
71.6 min) is mapped to the host clock by :class:`ClockOffsetEstimator`.

This file holds protocol, calibration, clock filter and driver together (over the usual
400 lines) so that the driver is one self-contained unit the lead can wire to a node.
"""

from __future__ import annotations

import contextlib
import logging
import math
import termios
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import serial
import yaml

log = logging.getLogger(__name__)

_IO_ERRORS = (serial.SerialException, OSError, termios.error)  # termios.error is not an OSError

CHANNELS = ("SPS1", "SPS2", "SPS3", "S1")
"""Wire order of the four raw values: h1..h3 (surface profile sensors) and h4 (indenter)."""

SEQ_MOD = 1 << 32
CLOCK_MOD_US = 1 << 32
_MAX_LINE = 256


class FibreError(Exception):
    """Base class of fibre DAQ driver errors."""


class FibreCalibrationError(FibreError, ValueError):
    """A calibration file is missing, malformed or physically implausible."""


class FibreNotConnectedError(FibreError):
    """The DAQ is not connected (unplugged, or never found)."""


class FibreCommandError(FibreError):
    """The DAQ rejected a command, or did not answer it in time."""


# --- wire protocol ------------------------------------------------------------------------


def checksum(body: bytes) -> int:
    """NMEA checksum: XOR of every byte between ``$`` and ``*`` (exclusive)."""
    cs = 0
    for b in body:
        cs ^= b
    return cs


def encode_sentence(body: str) -> bytes:
    """Frame ``body`` (e.g. ``"RATE,500"``) as ``$RATE,500*HH\\r\\n``."""
    raw = body.encode("ascii")
    return b"$" + raw + b"*%02X\r\n" % checksum(raw)


class SentenceError(ValueError):
    """A line that is not a valid sentence; ``kind`` is ``"resync"`` or ``"corrupt"``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def decode_sentence(line: bytes, *, require_checksum: bool = True) -> tuple[list[str], bool]:
    """Split one received line (terminator stripped) into its comma-separated fields.

    Returns ``(fields, resynced)``: ``resynced`` is True when bytes before the last ``$``
    had to be discarded (garbage or the start of a truncated sentence). Raises
    :class:`SentenceError` (kind ``"resync"`` if there is no ``$`` at all, ``"corrupt"``
    for a missing or wrong checksum or non-ASCII bytes).
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


# --- calibration --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ChannelCalibration:
    """One channel's fit ``mm = sum(poly[k] * raw**k)``, valid for raw in ``raw_range``."""

    name: str
    poly: tuple[float, ...]
    raw_range: tuple[float, float]
    zero_mm: float = 0.0  # height this channel reads at the zero (tare) reference pose

    def height_mm(self, raw: float) -> float:
        """Height (mm) for a raw reading (ADC counts); extrapolates outside ``raw_range``."""
        acc = 0.0
        for c in reversed(self.poly):
            acc = acc * raw + c
        return acc

    def raw_for_height(self, mm: float) -> float:
        """Inverse of :meth:`height_mm` inside ``raw_range`` (bisection; the fit is monotonic)."""
        lo, hi = self.raw_range
        h_lo, h_hi = self.height_mm(lo), self.height_mm(hi)
        if not min(h_lo, h_hi) <= mm <= max(h_lo, h_hi):
            raise ValueError(f"{self.name}: {mm} mm outside the calibrated span [{min(h_lo, h_hi):.4g}, {max(h_lo, h_hi):.4g}] mm")
        rising = h_hi > h_lo
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if (self.height_mm(mid) < mm) == rising:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


@dataclass(frozen=True, slots=True)
class FibreCalibration:
    """Calibration of the four channels, in wire order (SPS1, SPS2, SPS3, S1)."""

    channels: tuple[ChannelCalibration, ...]
    source: str = "<memory>"

    def heights_mm(self, raw: Sequence[float], offsets_mm: Sequence[float] = (0.0, 0.0, 0.0, 0.0)) -> tuple[float, ...]:
        """Heights h1..h4 (mm) for four raw readings, plus per-channel tare offsets."""
        return tuple(ch.height_mm(r) + o for ch, r, o in zip(self.channels, raw, offsets_mm, strict=True))

    def raw_for_heights(self, heights_mm: Sequence[float]) -> tuple[float, ...]:
        """Raw readings that produce ``heights_mm`` (for emulators and tests)."""
        return tuple(ch.raw_for_height(h) for ch, h in zip(self.channels, heights_mm, strict=True))


def load_calibration(path: str | Path) -> FibreCalibration:
    """Load a fibre calibration YAML file (format in docs/devices.md).

    Raises:
        FibreCalibrationError: naming the file, the channel and what is wrong.
    """
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise FibreCalibrationError(f"{p}: cannot read calibration file: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise FibreCalibrationError(f"{p}: not valid YAML: {exc}") from None
    return calibration_from_dict(doc, source=str(p))


def calibration_from_dict(doc: Any, source: str = "<dict>") -> FibreCalibration:
    """Validate a parsed calibration document; see :func:`load_calibration`."""

    def fail(msg: str) -> FibreCalibrationError:
        return FibreCalibrationError(f"{source}: {msg}")

    if not isinstance(doc, dict) or not isinstance(doc.get("channels"), list):
        raise fail("expected a mapping with a 'channels' list")
    unknown = set(doc) - {"format", "description", "adc_bits", "channels"}
    if unknown:
        raise fail(f"unknown top-level keys {sorted(unknown)}")
    chans = doc["channels"]
    if len(chans) != len(CHANNELS):
        raise fail(f"expected {len(CHANNELS)} channels {list(CHANNELS)} in wire order, got {len(chans)}")
    out = []
    for i, (ch, expected_name) in enumerate(zip(chans, CHANNELS, strict=True)):
        where = f"channels[{i}]"
        if not isinstance(ch, dict):
            raise fail(f"{where}: expected a mapping, got {type(ch).__name__}")
        unknown = set(ch) - {"name", "poly", "raw_range", "zero_mm"}
        if unknown:
            raise fail(f"{where}: unknown keys {sorted(unknown)}")
        name = ch.get("name", expected_name)
        if name != expected_name:
            raise fail(f"{where}: name {name!r}, expected {expected_name!r} (wire order is {list(CHANNELS)})")
        poly = ch.get("poly")
        if not isinstance(poly, list) or not 2 <= len(poly) <= 8:
            raise fail(f"{where} ({name}): 'poly' must be a list of 2..8 coefficients, lowest order first")
        for k, c in enumerate(poly):
            if isinstance(c, bool) or not isinstance(c, int | float) or not math.isfinite(c):
                hint = " (YAML reads 1e-5 as a string: write 1.0e-5)" if isinstance(c, str) else ""
                raise fail(f"{where} ({name}): poly[{k}] = {c!r} is not a finite number{hint}")
        rr = ch.get("raw_range")
        if not (isinstance(rr, list) and len(rr) == 2 and all(isinstance(v, int | float) for v in rr) and rr[0] < rr[1]):
            raise fail(f"{where} ({name}): 'raw_range' must be [low, high] counts with low < high, got {rr!r}")
        zero = ch.get("zero_mm", 0.0)
        if not isinstance(zero, int | float):
            raise fail(f"{where} ({name}): 'zero_mm' must be a number, got {zero!r}")
        cal = ChannelCalibration(name, tuple(float(c) for c in poly), (float(rr[0]), float(rr[1])), float(zero))
        grid = [rr[0] + (rr[1] - rr[0]) * j / 200 for j in range(201)]
        diffs = [cal.height_mm(b) - cal.height_mm(a) for a, b in zip(grid, grid[1:], strict=False)]
        if not (all(d > 0 for d in diffs) or all(d < 0 for d in diffs)):
            raise fail(f"{where} ({name}): polynomial is not monotonic over raw_range {rr}; a displacement fit must be")
        out.append(cal)
    return FibreCalibration(tuple(out), source)


# --- device clock -> host clock --------------------------------------------------------


class ClockOffsetEstimator:
    """Maps device time to host time: ``host ≈ device + offset(device)``.

    Minimum-latency filter with drift: every ``block_s`` of device time keeps the sample
    with the smallest ``host - device`` (the one that crossed the wire fastest); a line is
    fitted through those block minima over the last ``window_s``, after discarding minima
    that sit well above the fit (a block in which the host was busy). Before three blocks
    exist the plain minimum is used. Drift is clamped to ``max_drift_ppm``.
    """

    def __init__(self, window_s: float = 10.0, block_s: float = 0.25, max_drift_ppm: float = 20000.0) -> None:
        if not 0 < block_s < window_s:
            raise ValueError(f"need 0 < block_s < window_s, got block_s={block_s}, window_s={window_s}")
        self._window_ns = int(window_s * 1e9)
        self._block_ns = int(block_s * 1e9)
        self._max_drift = max_drift_ppm * 1e-6
        self.reset()

    def reset(self) -> None:
        """Forget everything (after a reconnect or a device reboot)."""
        self._blocks: deque[tuple[int, int]] = deque()  # (device_ns, min host-device)
        self._cur: tuple[int, int, int] | None = None  # (block index, device_ns, min d)
        self._fit: tuple[int, float, float] | None = None  # (t_ref, offset at t_ref, slope)

    def update(self, device_ns: int, host_ns: int) -> None:
        """Add one (device stamp, host receive stamp) pair, both in ns."""
        d = host_ns - device_ns
        idx = device_ns // self._block_ns
        if self._cur is None or idx != self._cur[0]:
            if self._cur is not None:
                self._blocks.append((self._cur[1], self._cur[2]))
                while self._blocks and device_ns - self._blocks[0][0] > self._window_ns:
                    self._blocks.popleft()
                self._refit()
            self._cur = (idx, device_ns, d)
        elif d < self._cur[2]:
            self._cur = (idx, device_ns, d)

    def _refit(self) -> None:
        pts = list(self._blocks)
        if len(pts) < 3:
            self._fit = None
            return
        for _ in range(2):
            t_ref = pts[-1][0]
            n = len(pts)
            mx = sum(t - t_ref for t, _ in pts) / n
            my = sum(d for _, d in pts) / n
            sxx = sum((t - t_ref - mx) ** 2 for t, _ in pts)
            slope = sum((t - t_ref - mx) * (d - my) for t, d in pts) / sxx if sxx > 0 else 0.0
            slope = max(-self._max_drift, min(self._max_drift, slope))
            a = my - slope * mx
            resid = [d - (a + slope * (t - t_ref)) for t, d in pts]
            mad = sorted(abs(r) for r in resid)[n // 2]
            keep = [p for p, r in zip(pts, resid, strict=True) if r <= 3.0 * mad + 20_000]
            if len(keep) == n or len(keep) < 3:
                break
            pts = keep
        self._fit = (t_ref, a, slope)

    @property
    def ready(self) -> bool:
        """True once at least one sample was seen."""
        return self._cur is not None

    @property
    def drift_ppm(self) -> float:
        """Estimated device clock rate error (ppm; positive: device clock slow)."""
        return 0.0 if self._fit is None else self._fit[2] * 1e6

    def offset_ns(self, device_ns: int | None = None) -> int | None:
        """Offset (host - device, ns) at ``device_ns`` (default: the latest sample)."""
        if self._cur is None:
            return None
        if device_ns is None:
            device_ns = self._cur[1]
        if self._fit is None:
            return min([self._cur[2], *(d for _, d in self._blocks)])
        t_ref, a, slope = self._fit
        return round(a + slope * (device_ns - t_ref))

    def to_host_ns(self, device_ns: int) -> int | None:
        """Device stamp (ns) expressed on the host clock, or None before the first sample."""
        off = self.offset_ns(device_ns)
        return None if off is None else device_ns + off


# --- driver interface ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FibreSample:
    """One DAQ sample.

    Attributes:
        host_stamp_ns: host clock when the line was received (includes transport jitter).
        device_stamp_ns: device clock at sampling (ns), unwrapped; continuous within one
            connection (restarts from the raw 32-bit value after a reconnect).
        seq: device sequence number (32-bit, wraps).
        raw: the four raw readings (ADC counts), wire order SPS1, SPS2, SPS3, S1.
        heights_mm: h1..h4 in mm (calibrated, tare offsets applied).
        stamp_ns: sampling instant on the host clock (device stamp + estimated offset);
            the jitter-free stamp to publish. Equals host_stamp_ns until a first estimate.
    """

    host_stamp_ns: int
    device_stamp_ns: int
    seq: int
    raw: tuple[float, float, float, float]
    heights_mm: tuple[float, float, float, float]
    stamp_ns: int = 0


@dataclass(frozen=True, slots=True)
class FibreCounters:
    """Error counters since open(); none of these events is fatal."""

    samples: int = 0
    resyncs: int = 0  # bytes discarded to find the next '$' (garbage, truncated lines)
    corrupt: int = 0  # sentences with a bad/missing checksum or malformed fields
    dropped: int = 0  # sequence numbers never received (gaps within one connection)
    reconnects: int = 0  # successful re-openings after losing the port
    overruns: int = 0  # samples discarded because the caller did not read() in time
    out_of_range: int = 0  # samples with a raw value outside its calibrated range


@dataclass(frozen=True, slots=True)
class FibreStatus:
    """Snapshot of the driver state (cheap; call as often as you like)."""

    connected: bool
    last_error: str | None
    counters: FibreCounters
    clock_offset_ns: int | None  # host - device at the latest sample; None before data
    clock_drift_ppm: float = 0.0
    rate_hz: float | None = None  # last rate confirmed by the device (None: device default)
    port: str = ""


@runtime_checkable
class FibreDriver(Protocol):
    """What the fibre reader node needs from a backend (serial DAQ or simulation)."""

    def open(self) -> None:
        """Connect and start acquiring."""

    def read(self, timeout_s: float) -> list[FibreSample]:
        """All samples received since the last call; waits up to ``timeout_s`` for one.

        Returns [] on timeout or while the device is disconnected; never raises for I/O.
        """

    def status(self) -> FibreStatus:
        """Connection state, error counters and clock estimate."""

    def set_rate(self, hz: float) -> None:
        """Set the sampling rate (Hz); kept and re-applied after a reconnect."""

    def zero(self) -> None:
        """Tare: the current pose reads the calibration's ``zero_mm`` heights from now on."""

    def close(self) -> None:
        """Stop acquisition and release the port (idempotent)."""



# --- serial driver ------------------------------------------------------------------------


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
        clock: host clock in ns (default wall clock ``time.time_ns``; inject the node's).
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
        clock: Callable[[], int] = time.time_ns,
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
        self._reply: list[str] | None = None
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
                    self._ser.write(encode_sentence("STOP"))
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
                self._write(encode_sentence(",".join((cmd, *args))))
                with self._cond:
                    self._cond.wait_for(lambda: self._reply is not None or not self._connected, self._cmd_timeout)
                    reply = self._reply
            finally:
                with self._cond:
                    self._reply_wanted = None
        if reply is None:
            raise FibreCommandError(f"{self._port}: no reply to ${cmd} within {self._cmd_timeout} s")
        if reply[2] != "OK":
            raise FibreCommandError(f"{self._port}: device rejected ${cmd}: {','.join(reply[3:]) or 'no reason given'}")
        return reply[3:]

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
            self._write(encode_sentence("START"))
            if self._desired_rate is not None:
                self._write(encode_sentence(f"RATE,{self._desired_rate:g}"))
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
                if len(buf) > _MAX_LINE:  # no terminator in sight: garbage
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
        elif fields[0] == "R" and len(fields) >= 3:
            with self._cond:
                if fields[1] == "RATE" and fields[2] == "OK" and len(fields) > 3:
                    with contextlib.suppress(ValueError):
                        self._confirmed_rate = float(fields[3])
                if fields[1] == self._reply_wanted:
                    self._reply = fields
                    self._cond.notify_all()
        else:
            log.debug("fibre DAQ %s: ignoring sentence %r", self._port, fields[0])

    def _handle_data(self, fields: list[str], host_ns: int) -> None:
        try:
            if len(fields) != 7:
                raise ValueError(f"{len(fields)} fields, expected 7")
            seq, t_us = int(fields[1]), int(fields[2])
            r = [float(v) for v in fields[3:7]]
            if not (0 <= seq < SEQ_MOD and 0 <= t_us < CLOCK_MOD_US and all(math.isfinite(v) for v in r)):
                raise ValueError("value out of range")
        except ValueError as exc:
            self._bump("corrupt", f"{self._port}: malformed data sentence ({exc}): {','.join(fields)[:60]}")
            return
        raw = (r[0], r[1], r[2], r[3])
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
