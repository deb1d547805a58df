"""Stiffness estimates, maps and detected inclusions."""

from __future__ import annotations

import msgspec

from palpa.message import Finite, Message


class StiffnessSample(Message, frozen=True, kw_only=True):
    """One stiffness estimate at one place (topic ``stiffness/sample``).

    ``model`` is ``airfloat`` (``value`` = Young's modulus E in kPa, eq. 7) or ``multi_indenter`` (``value`` =
    tissue stiffness K_t in N/mm, eq. 5). ``valid`` is True only for a stiffness reading of the specimen; every
    other reading (the probe in the air, the air-float ring off the measured footprint, the indenter on its stop
    during a lift or a touch-off, stale inputs...) carries ``valid=False``, a NaN ``value`` and a ``reason``
    (docs/custom-node.md lists them).
    """

    stamp_ns: int
    model: str
    x_mm: float
    y_mm: float
    z_mm: float
    value: float
    unit: str
    valid: bool
    reason: str = ""
    d_in_mm: float = 0.0
    force_n: float = 0.0
    tilt_rad: float = 0.0
    pan_rad: float = 0.0
    dt_mm: list[float] = []
    """Tissue displacement under each indenter (multi-indenter model)."""
    thickness_mm: float = 0.0
    """The layer thickness eq. 7 used here (air-float model; 0: not stated)."""


class StiffnessFit(Message, frozen=True, kw_only=True):
    """Fit of one force-depth curve from a pressure ramp (topic ``stiffness/fit``): eqs. 6, 7 and 8."""

    stamp_ns: int
    x_mm: float
    y_mm: float
    e_hertz_kpa: float
    e_corrected_kpa: float
    e_fung_kpa: float
    b_fung: float
    points: int
    rms_residual_n: float
    max_depth_mm: float


class StiffnessMap(Message, frozen=True, kw_only=True):
    """The gridded map (topic ``map/stiffness``, latched). ``stiffness`` is row-major ny x nx, NaN = no data."""

    stamp_ns: int
    unit: str
    x_mm: list[float]
    y_mm: list[float]
    stiffness: list[float]
    count: list[int]
    spread: list[float]
    samples: int
    final: bool = False


class DetectedInclusion(msgspec.Struct, frozen=True, kw_only=True):
    """One stiff region: centroid, equivalent radius and contrast (peak / healthy baseline); the detector's
    significance ``snr`` (σ of the filtered noise) and ``false_alarm``, the probability that a map without
    inclusions shows a peak that significant (models.detector). A sender from before issue 37 leaves them
    at 0 and 1 (not known)."""

    x_mm: Finite
    y_mm: Finite
    radius_mm: Finite
    contrast: Finite
    snr: float = 0.0
    false_alarm: float = 1.0


class Inclusions(Message, frozen=True, kw_only=True):
    """Inclusions detected in the map (topic ``map/inclusions``, latched)."""

    stamp_ns: int
    unit: str
    baseline: float
    inclusions: list[DetectedInclusion]
    final: bool = False
    threshold_snr: float = 0.0
    """The significance a detection had to exceed on this map (0: not stated)."""
    false_alarm_per_map: float = 0.0
    """The detector's false-alarm rate per map without inclusions (0: not stated)."""
