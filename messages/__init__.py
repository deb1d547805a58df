"""Typed messages of the palpation graph (units in field names: mm, kPa, N, N/mm, rad, ns, s).

Every type is a frozen, keyword-only ``palpa.Message`` encoded as a msgpack map; ``palpa.lookup(name)`` finds it
by the name carried in the envelope header. Stamps (``stamp_ns``) are host wall-clock ns since the Unix epoch,
taken when the measurement was made (not when it was published).

``messages.foxglove`` mirrors Foxglove's own schemas (metres, not mm) for the live views (nodes/mapping/foxglove_views.py).

Evolution policy: add fields only with defaults; never reuse, rename or retype a field; a new meaning gets a new
type name. See docs/wire.md.
"""

from messages.foxglove import FrameTransform, Grid, ImageAnnotations, RawImage, SceneUpdate
from messages.probe import (
    DeviceStatus,
    ImageInfo,
    IndenterDisplacements,
    PressureCommand,
    PressureState,
    ProbeHeights,
)
from messages.robot import EStop, PlanWaypoint, RobotPose, ScanPlan, ScanStatus, TableHeight
from messages.services import (
    MapSaved,
    PressureAck,
    ProbeAt,
    ProbeResult,
    SetPressure,
    Trigger,
    TriggerResult,
)
from messages.std import Text
from messages.stiffness import (
    DetectedInclusion,
    Inclusions,
    StiffnessFit,
    StiffnessMap,
    StiffnessSample,
)
from palpa.runtime_msgs import ClockTick, Heartbeat, LogRecord

__all__ = [
    "ClockTick",
    "DetectedInclusion",
    "DeviceStatus",
    "EStop",
    "FrameTransform",
    "Grid",
    "Heartbeat",
    "ImageAnnotations",
    "ImageInfo",
    "Inclusions",
    "IndenterDisplacements",
    "LogRecord",
    "MapSaved",
    "PlanWaypoint",
    "PressureAck",
    "PressureCommand",
    "PressureState",
    "ProbeAt",
    "ProbeHeights",
    "ProbeResult",
    "RawImage",
    "RobotPose",
    "ScanPlan",
    "SceneUpdate",
    "ScanStatus",
    "SetPressure",
    "StiffnessFit",
    "StiffnessMap",
    "StiffnessSample",
    "TableHeight",
    "Text",
    "Trigger",
    "TriggerResult",
]
