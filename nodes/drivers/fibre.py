"""Fibre-optic displacement DAQ: the driver interface the fibre reader node uses, and its value types.

The DAQ (a microcontroller sampling four Keyence FS-N10 amplifiers: the surface profile sensors SPS1,
SPS2, SPS3 and the indenter S1) is specified in ``docs/devices.md``. Two backends implement
:class:`FibreDriver`: ``fibre_serial.SerialFibreDriver`` (the DAQ on a serial line) and
``fibre_sim.SimFibreDriver`` (a simulated probe over a phantom).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable


class FibreError(Exception):
    """Base class of fibre DAQ driver errors."""


class FibreNotConnectedError(FibreError):
    """The DAQ is not connected (unplugged, or never found)."""


class FibreCommandError(FibreError):
    """The DAQ rejected a command, or did not answer it in time."""


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
