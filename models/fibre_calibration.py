"""Calibration of the fibre DAQ's four channels: raw ADC counts -> heights h1..h4 in mm.

Each channel has a polynomial fit (paper 1, Fig. 3) over the raw range where it holds; the file format is
in ``docs/devices.md`` ("Calibration file"). Pure: the loader reads one YAML file and nothing else, through
:mod:`yamlstruct` (the project's one YAML loader), so every error names ``file:line:col``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar

import msgspec

from devices.fibre_daq import CHANNELS
from yamlstruct import Source, convert


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


class _CalibrationSource(Source):
    error_type: ClassVar[type[Exception]] = FibreCalibrationError
    document: ClassVar[str] = "the calibration file"


class _ChannelDecl(msgspec.Struct, forbid_unknown_fields=True):
    poly: Annotated[list[float], msgspec.Meta(min_length=2, max_length=8)]
    raw_range: tuple[float, float]
    name: str | None = None
    zero_mm: float = 0.0


class _CalibrationFile(msgspec.Struct, forbid_unknown_fields=True):
    channels: list[_ChannelDecl]
    format: int | str | None = None
    description: str | None = None
    adc_bits: int | None = None


def load_calibration(path: str | Path) -> FibreCalibration:
    """Load a fibre calibration YAML file (format in docs/devices.md).

    Raises:
        FibreCalibrationError: ``file:line:col:`` and what is wrong (the channel, the key).
    """
    p = Path(path)
    return _calibration(_CalibrationSource.read(p), str(p))


def calibration_from_dict(doc: Any, source: str = "<dict>") -> FibreCalibration:
    """Validate a parsed calibration document; see :func:`load_calibration` (errors name ``source`` only)."""
    return _calibration(_CalibrationSource(path=Path(source), name=source, data=doc), source)


def _calibration(src: Source, source: str) -> FibreCalibration:
    if not isinstance(src.data, dict):
        raise src.error((), "expected a mapping with a 'channels' list")
    doc: _CalibrationFile = convert(src, src.data, _CalibrationFile)
    if len(doc.channels) != len(CHANNELS):
        raise src.error(("channels",), f"expected {len(CHANNELS)} channels {list(CHANNELS)} in wire order, "
                                       f"got {len(doc.channels)}")
    out = []
    for i, (ch, expected_name) in enumerate(zip(doc.channels, CHANNELS, strict=True)):
        where = ("channels", i)
        name = expected_name if ch.name is None else ch.name
        if name != expected_name:
            raise src.error((*where, "name"), f"channels[{i}]: name {name!r}, expected {expected_name!r} (wire order "
                                              f"is {list(CHANNELS)})")
        for k, c in enumerate(ch.poly):
            if not math.isfinite(c):
                raise src.error((*where, "poly", k), f"channels[{i}] ({name}): poly[{k}] = {c!r} is not finite")
        lo, hi = ch.raw_range
        if not lo < hi:
            raise src.error((*where, "raw_range"), f"channels[{i}] ({name}): 'raw_range' must be [low, high] counts "
                                                   f"with low < high, got {[lo, hi]!r}")
        cal = ChannelCalibration(name, tuple(ch.poly), (lo, hi), ch.zero_mm)
        grid = [lo + (hi - lo) * j / 200 for j in range(201)]
        diffs = [cal.height_mm(b) - cal.height_mm(a) for a, b in zip(grid, grid[1:], strict=False)]
        if not (all(d > 0 for d in diffs) or all(d < 0 for d in diffs)):
            raise src.error((*where, "poly"), f"channels[{i}] ({name}): polynomial is not monotonic over raw_range "
                                              f"{[lo, hi]}; a displacement fit must be")
        out.append(cal)
    return FibreCalibration(tuple(out), source)
