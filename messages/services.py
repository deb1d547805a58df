"""Requests and responses of the graph's services (palpa.node.service): probe a point, control a scan, change the
pressure set-point, tare the fibre sensors, save the map."""

from __future__ import annotations

from typing import Literal

from palpa.message import Message


class Trigger(Message, frozen=True, kw_only=True):
    """A request with no arguments (pause, resume, abort, tare, save)."""


class TriggerResult(Message, frozen=True, kw_only=True):
    """What a trigger did, in words (``state``: the node's state afterwards, where it has one)."""

    message: str
    state: str = ""


class ProbeAt(Message, frozen=True, kw_only=True):
    """Probe the tissue at (x, y) mm, phantom frame (service ``scanner/probe_at``).

    ``sweep``: slide the probe along a line of ``length_mm`` centred on the point (along the scanner's axis);
    ``indent``: press at the point. The stiffness is the median of the valid estimates within ``radius_mm`` measured
    while the probe slid along the line or pressed and held (not in transit, nor descending onto the line)."""

    x_mm: float
    y_mm: float
    mode: Literal["sweep", "indent"] = "sweep"
    length_mm: float = 6.0
    radius_mm: float = 2.0


class ProbeResult(Message, frozen=True, kw_only=True):
    """The stiffness found at a probed point: median ``value`` (``unit`` as the estimator's, kPa for the air-float
    model), the estimates it came from, and their median absolute deviation."""

    x_mm: float
    y_mm: float
    value: float
    unit: str
    samples: int
    mad: float
    duration_s: float
    measured_from_ns: int = 0
    """The span the estimates were measured in (stamps, ns): the probe on its measuring part, sliding along the line
    or pressing and holding. A caller binning the estimates itself keeps these, not the transit's (the air-float
    probe's floating indenter reads the tissue from several mm higher). 0 and 0: not said."""
    measured_to_ns: int = 0


class SetPressure(Message, frozen=True, kw_only=True):
    """A new pressure set-point (service ``pressure/set``): held, or ramped to at ``rate_kpa_s``. Refused above the
    controller's cap, never clamped silently."""

    setpoint_kpa: float
    mode: Literal["hold", "ramp"] = "hold"
    rate_kpa_s: float = 5.0


class PressureAck(Message, frozen=True, kw_only=True):
    """The set-point the controller now follows (or ramps towards), and its cap."""

    setpoint_kpa: float
    target_kpa: float
    max_kpa: float
    mode: str


class MapSaved(Message, frozen=True, kw_only=True):
    """Files written by ``map/save`` and how many samples the map holds."""

    paths: list[str]
    samples: int
