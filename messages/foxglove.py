"""Foxglove's well-known schemas as palpa messages, so a node can publish what the Foxglove app draws natively.

Field names and meanings follow Foxglove's schemas (foxglove.Grid, foxglove.SceneUpdate, ...); the type names
are theirs too, which is how the app picks its 3D and Image renderers for a channel. Only the parts palpa's views
use are typed; the other primitive lists of a SceneEntity are kept (empty) because the JSON form of a schema lists
every field. Lengths are in metres, as Foxglove expects. ``bytes`` fields travel as base64 in JSON.
"""

from __future__ import annotations

import msgspec

from palpa.message import Message

__all__ = [
    "CircleAnnotation", "Color", "CylinderPrimitive", "FrameTransform", "Grid", "ImageAnnotations",
    "LinePrimitive", "PackedElementField", "Point2", "Pose", "Quaternion", "RawImage", "SceneEntity",
    "SceneUpdate", "TextAnnotation", "TextPrimitive", "Time", "Vector2", "Vector3",
    "FLOAT32", "LINE_STRIP", "LINE_LOOP",
]

FLOAT32 = 7
"""PackedElementField.type of a little-endian 32-bit float."""
LINE_STRIP = 0
LINE_LOOP = 1


class _Part(msgspec.Struct, frozen=True, kw_only=True):
    pass


class Time(_Part, frozen=True, kw_only=True):
    sec: int
    nsec: int

    @classmethod
    def of(cls, ns: int) -> Time:
        """A timestamp from ns since the Unix epoch."""
        return cls(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


class Vector2(_Part, frozen=True, kw_only=True):
    x: float
    y: float


class Point2(_Part, frozen=True, kw_only=True):
    x: float
    y: float


class Vector3(_Part, frozen=True, kw_only=True):
    x: float
    y: float
    z: float


class Quaternion(_Part, frozen=True, kw_only=True):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(_Part, frozen=True, kw_only=True):
    position: Vector3
    orientation: Quaternion = Quaternion()


class Color(_Part, frozen=True, kw_only=True):
    r: float
    g: float
    b: float
    a: float = 1.0


class PackedElementField(_Part, frozen=True, kw_only=True):
    name: str
    offset: int
    type: int


class Grid(Message, frozen=True, kw_only=True):
    """A 2-D grid of cells in a frame; the 3D panel colours it by one of its fields."""

    type_name = "foxglove.Grid"
    timestamp: Time
    frame_id: str
    pose: Pose
    column_count: int
    cell_size: Vector2
    row_stride: int
    cell_stride: int
    fields: list[PackedElementField]
    data: bytes


class FrameTransform(Message, frozen=True, kw_only=True):
    """Where ``child_frame_id`` is in ``parent_frame_id``."""

    type_name = "foxglove.FrameTransform"
    timestamp: Time
    parent_frame_id: str
    child_frame_id: str
    translation: Vector3
    rotation: Quaternion


class CylinderPrimitive(_Part, frozen=True, kw_only=True):
    pose: Pose
    size: Vector3
    bottom_scale: float = 1.0
    top_scale: float = 1.0
    color: Color


class LinePrimitive(_Part, frozen=True, kw_only=True):
    type: int = LINE_STRIP
    pose: Pose
    thickness: float
    scale_invariant: bool = False
    points: list[Vector3]
    color: Color
    colors: list[Color] = []
    indices: list[int] = []


class TextPrimitive(_Part, frozen=True, kw_only=True):
    pose: Pose
    billboard: bool = True
    font_size: float
    scale_invariant: bool = True
    color: Color
    text: str


class SceneEntity(_Part, frozen=True, kw_only=True):
    timestamp: Time
    frame_id: str
    id: str
    lifetime: Time = Time(sec=0, nsec=0)
    """Zero: until replaced or deleted."""
    frame_locked: bool = True
    metadata: list[dict[str, str]] = []
    arrows: list[dict[str, float]] = []
    cubes: list[dict[str, float]] = []
    spheres: list[dict[str, float]] = []
    cylinders: list[CylinderPrimitive] = []
    lines: list[LinePrimitive] = []
    triangles: list[dict[str, float]] = []
    texts: list[TextPrimitive] = []
    models: list[dict[str, float]] = []


class SceneEntityDeletion(_Part, frozen=True, kw_only=True):
    timestamp: Time
    type: int
    """0: the entity with ``id``; 1: every entity of the topic."""
    id: str = ""


class SceneUpdate(Message, frozen=True, kw_only=True):
    """Entities to add or replace (by id) and to delete, in the 3D panel."""

    type_name = "foxglove.SceneUpdate"
    deletions: list[SceneEntityDeletion] = []
    entities: list[SceneEntity] = []


class RawImage(Message, frozen=True, kw_only=True):
    """An uncompressed image (``rgb8``: rows of R, G, B bytes)."""

    type_name = "foxglove.RawImage"
    timestamp: Time
    frame_id: str
    width: int
    height: int
    encoding: str
    step: int
    data: bytes


class CircleAnnotation(_Part, frozen=True, kw_only=True):
    timestamp: Time
    position: Point2
    diameter: float
    thickness: float
    fill_color: Color
    outline_color: Color


class TextAnnotation(_Part, frozen=True, kw_only=True):
    timestamp: Time
    position: Point2
    text: str
    font_size: float
    text_color: Color
    background_color: Color


class ImageAnnotations(Message, frozen=True, kw_only=True):
    """Shapes and text drawn over an image, in its pixel coordinates."""

    type_name = "foxglove.ImageAnnotations"
    circles: list[CircleAnnotation] = []
    points: list[dict[str, float]] = []
    texts: list[TextAnnotation] = []
