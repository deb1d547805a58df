"""Emulated fibre-optic displacement DAQ on a pty, speaking the protocol in docs/devices.md.

Streams ``$F,<seq>,<t_us>,<r1>,<r2>,<r3>,<r4>*HH`` lines at a configurable rate (default
500 Hz) with raw values from a pluggable source ``t_s -> 4 raw counts`` (default: a fixed
pose), answers ``$RATE``, ``$ZERO``, ``$ID``, ``$START``, ``$STOP``, and injects faults on
request: garbage bytes, dropped lines (sequence gaps), corrupt checksums, truncated lines,
unplug/replug. Its clock is a 32-bit microsecond counter with configurable start value and
drift, like a microcontroller's ``micros()``.

Run by hand: ``python -m emulators.fibre_daq`` prints the port path and streams until Ctrl-C
(or SIGTERM).
"""

from __future__ import annotations

import argparse
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Self

from devices.fibre_daq import (
    CHANNELS,
    CLOCK_MOD_US,
    SEQ_MOD,
    SentenceError,
    decode_sentence,
    encode_data,
    encode_reply,
)
from emulators.pty_device import PtyDevice, serve_until_signal
from models.fibre_calibration import FibreCalibration, load_calibration

RawSource = Callable[[float], Sequence[float]]
"""Device time in seconds since boot -> four raw ADC readings (SPS1, SPS2, SPS3, S1)."""

DEFAULT_RAW = (21000.0, 21500.0, 20500.0, 33000.0)
RATE_RANGE_HZ = (1.0, 2000.0)
ADC_MAX = 65535
FIRMWARE = "fw1.2"


def fixed_pose(raw: Sequence[float] = DEFAULT_RAW) -> RawSource:
    """A source that always returns ``raw``."""
    values = tuple(float(v) for v in raw)
    return lambda _t: values


def source_from_heights(calibration: FibreCalibration, heights_mm: Callable[[float], Sequence[float]]) -> RawSource:
    """A source that produces the raw counts for heights ``heights_mm(t)`` (mm) through the
    inverse of ``calibration``; use it to drive the emulator from a simulated world."""
    return lambda t: calibration.raw_for_heights(heights_mm(t))


class FibreDaqEmulator(PtyDevice):
    """The DAQ on a pty. Start with :meth:`start` (or ``with``); the driver opens :attr:`port`.

    Args:
        source: raw value generator (see :data:`RawSource`); default :func:`fixed_pose`.
        rate_hz: boot-time sampling rate.
        clock_start_us: value of the device clock at boot (set near 2**32 to test wrap).
        drift_ppm: device clock rate error; positive runs fast.
        noise_counts: standard deviation of Gaussian noise added to raw values.
        stream_on_boot: stream without waiting for ``$START``.
        name, link_path: see :class:`PtyDevice`.
    """

    def __init__(
        self,
        source: RawSource | None = None,
        rate_hz: float = 500.0,
        *,
        clock_start_us: int = 0,
        drift_ppm: float = 0.0,
        noise_counts: float = 0.0,
        seed: int = 0,
        stream_on_boot: bool = True,
        name: str = "palpa-fibre-daq",
        link_path: str | None = None,
    ) -> None:
        super().__init__(name=name, link_path=link_path)
        self.source = source or fixed_pose()
        self._boot_rate = float(rate_hz)
        self._clock_start_us = int(clock_start_us) % CLOCK_MOD_US
        self._drift = drift_ppm * 1e-6
        self._noise = noise_counts
        self._rng = random.Random(seed)
        self._stream_on_boot = stream_on_boot
        self._state_lock = threading.Lock()
        self._faults: deque[str] = deque()
        self._recent_raw: deque[tuple[float, ...]] = deque(maxlen=16)
        self.sample_wall_ns: deque[tuple[int, int]] = deque(maxlen=20000)
        """(seq, host wall-clock ns of the sampling instant) of recent samples, for tests."""
        self.lines_sent = 0
        self.commands: list[str] = []
        self._stream_stop = threading.Event()
        self._stream_thread: threading.Thread | None = None
        self._boot()

    def _boot(self) -> None:
        with self._state_lock:
            self.seq = 0
            self.rate_hz = self._boot_rate
            self.streaming = self._stream_on_boot
            self._boot_mono_ns = time.monotonic_ns()
            self._wall_minus_mono = time.time_ns() - self._boot_mono_ns
            self._next_tick = self._boot_mono_ns
            self._faults.clear()
            self._recent_raw.clear()

    # -- lifecycle -------------------------------------------------------------------

    def start(self) -> Self:
        """Create the pty and start streaming."""
        super().start()
        with self._state_lock:
            self._next_tick = time.monotonic_ns()
        self._stream_stop.clear()
        self._stream_thread = threading.Thread(target=self._stream_loop, name="fibre-daq-stream", daemon=True)
        self._stream_thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop streaming and remove the pty (idempotent)."""
        self._stream_stop.set()
        if self._stream_thread is not None:
            self._stream_thread.join(timeout_s)
            self._stream_thread = None
        super().stop(timeout_s)

    def replug(self, reboot: bool = True) -> None:
        """Plug back in; with ``reboot`` the device restarts (seq 0, clock 0, boot rate)."""
        if self.plugged:
            raise RuntimeError(f"FibreDaqEmulator {self.port} is already plugged in")
        if reboot:
            self._clock_start_us = 0
            self._boot()
        super().replug()

    # -- fault injection -------------------------------------------------------------

    def inject_garbage(self, data: bytes = b"\x00\xff#noise\xfe") -> None:
        """Write ``data`` between two lines right now."""
        self.write(data)

    def drop_next(self, n: int = 1) -> None:
        """Skip sending the next ``n`` lines (their sequence numbers are used up)."""
        self._queue_fault("drop", n)

    def corrupt_next(self, n: int = 1) -> None:
        """Send the next ``n`` lines with a wrong checksum."""
        self._queue_fault("corrupt", n)

    def truncate_next(self, n: int = 1) -> None:
        """Send only the first half of the next ``n`` lines, without terminator."""
        self._queue_fault("partial", n)

    def _queue_fault(self, kind: str, n: int) -> None:
        with self._state_lock:
            self._faults.extend([kind] * n)

    @property
    def pending_faults(self) -> int:
        """Queued line faults not yet applied."""
        with self._state_lock:
            return len(self._faults)

    # -- device behaviour ------------------------------------------------------------

    def device_time_us(self, mono_ns: int) -> int:
        """The device clock (wrapping 32-bit µs) at host monotonic time ``mono_ns``."""
        elapsed = (mono_ns - self._boot_mono_ns) * (1.0 + self._drift)
        return (self._clock_start_us + int(elapsed // 1000)) % CLOCK_MOD_US

    def _sample(self, tick_ns: int) -> bytes | None:
        with self._state_lock:
            seq = self.seq
            self.seq = (seq + 1) % SEQ_MOD
            fault = self._faults.popleft() if self._faults else None
        t_us = self.device_time_us(tick_ns)
        raw = [float(v) for v in self.source((tick_ns - self._boot_mono_ns) * (1.0 + self._drift) / 1e9)]
        if len(raw) != len(CHANNELS):
            raise ValueError(f"fibre source returned {len(raw)} values, expected {len(CHANNELS)}")
        if self._noise:
            raw = [v + self._rng.gauss(0.0, self._noise) for v in raw]
        counts = [min(ADC_MAX, max(0, round(v))) for v in raw]
        self._recent_raw.append(tuple(float(c) for c in counts))
        self.sample_wall_ns.append((seq, tick_ns + self._wall_minus_mono))
        if fault == "drop":
            return None
        line = encode_data(seq, t_us, counts)
        if fault == "corrupt":
            bad = (int(line[-4:-2], 16) ^ 0x5A) & 0xFF
            line = line[:-4] + b"%02X\r\n" % bad
        elif fault == "partial":
            line = line[: len(line) // 2]
        return line

    def _stream_loop(self) -> None:
        while not self._stream_stop.is_set():
            now = time.monotonic_ns()
            with self._state_lock:
                streaming, period_ns, tick = self.streaming, int(1e9 / self.rate_hz), self._next_tick
                if not streaming:
                    self._next_tick = now
            if not streaming:
                self._stream_stop.wait(0.01)
                continue
            if now < tick:
                self._stream_stop.wait((tick - now) / 1e9)
                continue
            for _ in range(100):  # catch up after a stall, in bounded bursts
                line = self._sample(tick)
                if line is not None and self.write(line):
                    self.lines_sent += 1
                tick += period_ns
                if tick > now:
                    break
            with self._state_lock:
                if self._next_tick < tick:  # unless a $RATE/$START moved it meanwhile
                    self._next_tick = tick

    def handle_line(self, line: bytes) -> None:
        """Execute one command line from the host and reply."""
        try:
            fields, _ = decode_sentence(line, require_checksum=False)
        except SentenceError as exc:
            self.write(encode_reply("?", False, "checksum" if exc.kind == "corrupt" else "syntax"))
            return
        cmd, args = fields[0].upper(), fields[1:]
        self.commands.append(cmd)
        if cmd == "RATE":
            try:
                hz = float(args[0])
            except (IndexError, ValueError):
                self._reply(cmd, False, "expected RATE,<hz>")
                return
            lo, hi = RATE_RANGE_HZ
            if not lo <= hz <= hi:
                self._reply(cmd, False, f"range {lo:g}..{hi:g}")
                return
            with self._state_lock:
                self.rate_hz = hz
                self._next_tick = time.monotonic_ns() + int(1e9 / hz)
            self._reply(cmd, True, f"{hz:g}")
        elif cmd == "ZERO":
            with self._state_lock:
                recent = list(self._recent_raw)
            if not recent:
                recent = [tuple(float(v) for v in self.source(0.0))]
            means = [sum(col) / len(recent) for col in zip(*recent, strict=True)]
            self._reply(cmd, True, *(f"{m:.1f}" for m in means))
        elif cmd == "ID":
            self._reply(cmd, True, "palpa-fibre-daq", FIRMWARE, "SN0001", ":".join(CHANNELS))
        elif cmd in ("START", "STOP"):
            with self._state_lock:
                self.streaming = cmd == "START"
                self._next_tick = time.monotonic_ns()
            self._reply(cmd, True)
        else:
            self._reply(cmd, False, "unknown command")

    def _reply(self, cmd: str, ok: bool, *data: str) -> None:
        self.write(encode_reply(cmd, ok, *data))


def main(argv: list[str] | None = None) -> int:
    """``python -m emulators.fibre_daq``: run the emulator until Ctrl-C."""
    ap = argparse.ArgumentParser(prog="python -m emulators.fibre_daq", description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=500.0, help="boot sampling rate, Hz (default 500)")
    ap.add_argument("--link", help="symlink path to create (default /tmp/palpa-pty-*/palpa-fibre-daq)")
    ap.add_argument("--heights", type=float, nargs=4, metavar="MM", help="fixed heights h1..h4 in mm (needs --calibration)")
    ap.add_argument("--calibration", type=Path, help="calibration YAML used to turn --heights into raw counts")
    ap.add_argument("--noise", type=float, default=0.0, help="raw noise standard deviation, counts")
    ap.add_argument("--drift-ppm", type=float, default=0.0, help="device clock drift, ppm")
    ap.add_argument("--chaos", type=float, default=0.0, help="probability per second of injecting a random fault (0..1)")
    args = ap.parse_args(argv)
    source: RawSource | None = None
    if args.heights:
        if args.calibration is None:
            ap.error("--heights needs --calibration")
        cal = load_calibration(args.calibration)
        raw = cal.raw_for_heights(args.heights)
        source = fixed_pose(raw)
    emu = FibreDaqEmulator(source, args.rate, noise_counts=args.noise, drift_ppm=args.drift_ppm, link_path=args.link)
    rng = random.Random()
    faults: list[Callable[[], None]] = [emu.inject_garbage, emu.drop_next, emu.corrupt_next, emu.truncate_next]

    def chaos() -> None:
        if args.chaos > 0 and rng.random() < args.chaos:
            rng.choice(faults)()

    return serve_until_signal(emu, chaos)


if __name__ == "__main__":
    raise SystemExit(main())
