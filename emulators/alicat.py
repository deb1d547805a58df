"""Emulated Alicat pressure controller on a pty, speaking the Alicat serial ASCII protocol.

The valve drives a first-order regulator plant (:class:`models.regulator.RegulatorPlant`,
lag + slew limit + hard cap), advanced lazily to "now" before each command, so the
pressure evolves in real time without a thread. Commands (case-insensitive, ``\\r``-ended,
first character the unit id or ``*``; commands for another unit id are ignored as on a
multi-drop bus)::

    A           poll             -> data frame  "A +030.00 +030.00 [EXH] [HLD] [OPL]"
    AS<v>, AS <v>, A<int>        -> new set-point (float in device units; int: 64000 = full scale)
    AHP / AH    hold valve at its current position (HLD)
    AHC         hold valve closed (HLD; the probe leaks down through its tip)
    AE          exhaust (EXH; pressure falls to 0)
    AC          cancel hold / exhaust / a tripped over-pressure limit
    AVE         firmware version      AR<n> / AW<n>=<v>   registers (e.g. 122 control point)
    anything else                -> "?"

``$$`` before a command (legacy firmware syntax used by some clients) is accepted.
Faults: :meth:`fail_next` (``?`` replies), :meth:`mute_next`/:attr:`muted` (no reply),
:meth:`stick_valve` (read-back far from the set-point), unplug/replug (:class:`PtyDevice`).

Run by hand: ``python -m emulators.alicat`` prints the port path and runs until Ctrl-C
(or SIGTERM).
"""

from __future__ import annotations

import argparse
import random
import threading
import time
from collections.abc import Callable

from devices.alicat import (
    KPA_PER_UNIT,
    TERMINATOR,
    UNKNOWN,
    decode_command,
    encode_frame,
    encode_text_reply,
)
from emulators.pty_device import PtyDevice, serve_until_signal
from models.regulator import RegulatorPlant

FIRMWARE = "10v05.0-R24 emulated"
FULL_SCALE_COUNTS = 64000
_UNKNOWN_REPLY = UNKNOWN.encode("ascii") + TERMINATOR


class AlicatEmulator(PtyDevice):
    """An Alicat PC-series pressure controller (single inlet valve) on a pty.

    Args:
        unit_id: device unit id letter.
        full_scale_kpa: device range; also the plant's hard cap (supply pressure).
        tau_s, rate_limit_kpa_s: plant lag (s) and slew limit (kPa/s).
        device_unit: engineering unit used on the wire (key of KPA_PER_UNIT).
        opl_kpa: over-pressure limit: above it the device exhausts and shows OPL until AC.
        noise_kpa: Gaussian noise on the reported pressure.
        clock: monotonic seconds (inject a fake clock to step the plant deterministically).
    """

    def __init__(
        self,
        unit_id: str = "A",
        *,
        full_scale_kpa: float = 100.0,
        tau_s: float = 0.05,
        rate_limit_kpa_s: float = 200.0,
        pressure_kpa: float = 0.0,
        device_unit: str = "kPa",
        opl_kpa: float | None = None,
        noise_kpa: float = 0.0,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        name: str = "palpa-alicat",
        link_path: str | None = None,
    ) -> None:
        super().__init__(name=name, link_path=link_path)
        self.unit_id = unit_id.upper()
        self.full_scale_kpa = float(full_scale_kpa)
        self.plant = RegulatorPlant(tau_s=tau_s, rate_limit_kpa_s=rate_limit_kpa_s, max_kpa=full_scale_kpa, pressure_kpa=pressure_kpa)
        self._k = KPA_PER_UNIT[device_unit]
        self.opl_kpa = opl_kpa
        self._noise = noise_kpa
        self._rng = random.Random(seed)
        self._clock = clock
        self._state_lock = threading.Lock()
        self._t = clock()
        self.setpoint_kpa = 0.0
        self.mode = "control"  # control | hold | hold_closed | exhaust
        self.opl_tripped = False
        self.registers: dict[int, int] = {122: 38, 91: 50}  # 122: control point (38 gauge pressure), 91: stream ms
        self._fail_next = 0
        self._mute_next = 0
        self.muted = False
        """While True the device hears nothing and answers nothing (a hung or mis-wired unit)."""
        self.stuck: str | None = None
        self.commands: list[str] = []  # every line received, for tests

    # -- fault injection -------------------------------------------------------------

    def fail_next(self, n: int = 1) -> None:
        """Answer ``?`` to the next ``n`` commands (without executing them)."""
        with self._state_lock:
            self._fail_next += n

    def mute_next(self, n: int = 1) -> None:
        """Ignore the next ``n`` commands entirely (the host times out)."""
        with self._state_lock:
            self._mute_next += n

    def stick_valve(self, how: str | None) -> None:
        """Jam the valve: ``"frozen"`` (pressure stays), ``"open"`` (rises to full scale),
        ``"closed"`` (falls to 0), or None to free it. The set-point still echoes."""
        if how not in (None, "frozen", "open", "closed"):
            raise ValueError(f"stick_valve: expected None, 'frozen', 'open' or 'closed', got {how!r}")
        with self._state_lock:
            self._advance()
            self.stuck = how

    # -- plant -----------------------------------------------------------------------

    @property
    def pressure_kpa(self) -> float:
        """True plant pressure (kPa) now."""
        with self._state_lock:
            self._advance()
            return self.plant.pressure_kpa

    def _advance(self) -> None:
        now = self._clock()
        dt, self._t = max(0.0, now - self._t), now
        target: float | None
        if self.stuck == "frozen" or (self.stuck is None and self.mode == "hold"):
            target = None
        elif self.stuck == "open":
            target = self.full_scale_kpa
        elif self.stuck == "closed" or self.mode in ("hold_closed", "exhaust") or self.opl_tripped:
            target = 0.0
        else:
            target = self.setpoint_kpa
        if target is not None:
            self.plant.step(target, dt)
        if self.opl_kpa is not None and self.plant.pressure_kpa > self.opl_kpa:
            self.opl_tripped = True

    def _frame(self) -> bytes:
        p = self.plant.pressure_kpa + (self._rng.gauss(0.0, self._noise) if self._noise else 0.0)
        codes = []
        if self.mode == "exhaust" or self.opl_tripped:
            codes.append("EXH")
        if self.mode in ("hold", "hold_closed"):
            codes.append("HLD")
        if self.opl_tripped:
            codes.append("OPL")
        if p > self.full_scale_kpa * 1.0001:
            codes.append("POV")
        return encode_frame(self.unit_id, p / self._k, self.setpoint_kpa / self._k, codes)

    # -- protocol --------------------------------------------------------------------

    def handle_line(self, line: bytes) -> None:
        """Execute one received command line and reply (or not)."""
        decoded = decode_command(line)
        if decoded is None:
            return
        target, rest = decoded
        if target not in (self.unit_id, "*"):
            return  # addressed to another device on the bus
        with self._state_lock:
            self.commands.append(line.decode("ascii", "replace").strip())
            if self.muted:
                return
            if self._mute_next:
                self._mute_next -= 1
                return
            if self._fail_next:
                self._fail_next -= 1
                reply = _UNKNOWN_REPLY
            else:
                self._advance()
                reply = self._execute(rest)
        self.write(reply)

    def _execute(self, cmd: str) -> bytes:
        if cmd == "":
            return self._frame()
        if cmd.isdigit():
            return self._set(int(cmd) / FULL_SCALE_COUNTS * self.full_scale_kpa)
        if cmd.startswith("S") and len(cmd) > 1:
            try:
                return self._set(float(cmd[1:].strip()) * self._k)
            except ValueError:
                return _UNKNOWN_REPLY
        if cmd in ("HP", "H"):
            self.mode = "hold"
            return self._frame()
        if cmd == "HC":
            self.mode = "hold_closed"
            return self._frame()
        if cmd == "E":
            self.mode = "exhaust"
            return self._frame()
        if cmd == "C":
            self.mode = "control"
            self.opl_tripped = False
            return self._frame()
        if cmd == "VE":
            return encode_text_reply(self.unit_id, FIRMWARE)
        if cmd.startswith("R") and cmd[1:].isdigit() and int(cmd[1:]) in self.registers:
            reg = int(cmd[1:])
            return encode_text_reply(self.unit_id, f"{reg:03d} = {self.registers[reg]}")
        if cmd.startswith("W") and "=" in cmd:
            reg_s, _, val_s = cmd[1:].partition("=")
            if reg_s.strip().isdigit() and val_s.strip().isdigit() and int(reg_s) in self.registers:
                self.registers[int(reg_s)] = int(val_s)
                return encode_text_reply(self.unit_id, f"{int(reg_s):03d} = {int(val_s)}")
        return _UNKNOWN_REPLY

    def _set(self, kpa: float) -> bytes:
        # Clipped to the device range; the driver is what enforces the lower, safe maximum.
        self.setpoint_kpa = min(max(kpa, 0.0), self.full_scale_kpa)
        return self._frame()


def main(argv: list[str] | None = None) -> int:
    """``python -m emulators.alicat``: run the emulator until Ctrl-C."""
    ap = argparse.ArgumentParser(prog="python -m emulators.alicat", description=__doc__.split("\n\n")[0])
    ap.add_argument("--unit", default="A", help="unit id letter (default A)")
    ap.add_argument("--link", help="symlink path to create (default /tmp/palpa-pty-*/palpa-alicat)")
    ap.add_argument("--full-scale", type=float, default=100.0, help="device range, kPa (default 100)")
    ap.add_argument("--tau", type=float, default=0.05, help="plant lag, s")
    ap.add_argument("--rate-limit", type=float, default=200.0, help="plant slew limit, kPa/s")
    ap.add_argument("--unit-of-pressure", default="kPa", choices=sorted(KPA_PER_UNIT), help="engineering unit on the wire")
    ap.add_argument("--noise", type=float, default=0.0, help="pressure noise standard deviation, kPa")
    args = ap.parse_args(argv)
    emu = AlicatEmulator(
        args.unit,
        full_scale_kpa=args.full_scale,
        tau_s=args.tau,
        rate_limit_kpa_s=args.rate_limit,
        device_unit=args.unit_of_pressure,
        noise_kpa=args.noise,
        link_path=args.link,
    )
    return serve_until_signal(emu)


if __name__ == "__main__":
    raise SystemExit(main())
