"""Calibration of the fibre DAQ's four channels: raw ADC counts -> heights h1..h4 in mm.

Each channel has a polynomial fit (paper 1, Fig. 3) over the raw range where it holds; the file format is
in ``docs/devices.md`` ("Calibration file"). Pure: the loader reads one YAML file and nothing else.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from devices.fibre_daq import CHANNELS


class FibreCalibrationError(ValueError):
    """A calibration file is missing, malformed or physically implausible."""


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
