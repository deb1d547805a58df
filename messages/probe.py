"""Probe-side messages: fibre-optic heights, pressure, camera indenters, device status."""

from __future__ import annotations

from typing import Literal

from palpa.message import Finite, Message

Quad = tuple[float, float, float, float]


class ProbeHeights(Message, frozen=True, kw_only=True):
    """Air-float probe sensor extensions from the probe face (topic ``probe/heights``).

    ``h_mm`` = (h1, h2, h3, h4): the three surface-profile sensors SPS1..3 and the indenter S1, in mm, after
    calibration. ``d_in_mm`` and ``tilt_rad`` are eqs. 1-3 of the air-float paper computed from them.
    """

    stamp_ns: int
    seq: int
    h_mm: Quad
    raw: Quad
    d_in_mm: float
    tilt_rad: float
    valid: bool = True
    device_stamp_ns: int = 0


class PressureCommand(Message, frozen=True, kw_only=True):
    """A command to the pressure regulator (topic ``pressure/command``).

    ``hold``: go to ``setpoint_kpa`` and hold it; ``ramp``: rise (or fall) at ``rate_kpa_s`` to ``setpoint_kpa``
    (the paper's indentation test); ``vent``: go to 0 kPa. The regulator never exceeds its own hard cap whatever
    is asked.
    """

    mode: Literal["hold", "ramp", "vent"]
    setpoint_kpa: Finite = 0.0
    rate_kpa_s: Finite = 0.0


PressureMode = Literal["hold", "ramp", "vent"]
"""How the regulator drives its setpoint (commanded in ``PressureCommand.mode``, reported in ``PressureState``)."""
DeviceState = Literal["ok", "down", "reconnecting", "fault"]
"""A device driver's health in ``DeviceStatus``; on the wire a plain string."""


class PressureState(Message, frozen=True, kw_only=True):
    """The regulator's state (topic ``pressure/state``); ``force_n`` is eq. 4's indentation force."""

    stamp_ns: int
    setpoint_kpa: Finite
    measured_kpa: Finite
    force_n: Finite
    mode: PressureMode
    max_kpa: Finite
    faults: list[str] = []
    """Empty when healthy; e.g. ``device_lost``, ``tracking_error``, ``over_pressure``, ``clamped``."""


class IndenterDisplacements(Message, frozen=True, kw_only=True):
    """Camera-probe tracker output (topic ``camera/indenters``): one entry per indenter 1..4.

    ``displacement_mm`` is each indenter's travel from its rest (zero-reference) position; ``centroid_x_px`` the
    Kalman-filtered marker centroid; ``valid`` is False for a marker lost in this frame (predict-only).
    """

    stamp_ns: int
    frame_seq: int
    displacement_mm: Quad
    centroid_x_px: Quad
    centroid_y_px: Quad
    valid: tuple[bool, bool, bool, bool]


class DeviceStatus(Message, frozen=True, kw_only=True):
    """Health of one device driver (topics ``probe/status``, ``pressure/status``, ``camera/status``...)."""

    stamp_ns: int
    device: str
    connected: bool
    state: DeviceState
    message: str = ""
    counters: dict[str, int] = {}
    clock_offset_ns: int = 0


class ImageInfo(Message, frozen=True, kw_only=True):
    """Describes an image carried as the envelope's first binary blob (topic ``camera/debug``).

    ``encoding``: ``png`` or ``jpg`` (the blob is the encoded file; decode with ``cv2.imdecode``) or ``bgr8`` (raw
    rows of B, G, R bytes, ``height * width * 3`` of them). ``stamp_ns`` is the frame's capture stamp.
    """

    stamp_ns: int
    width: int
    height: int
    encoding: str
