"""Scan views for Foxglove: the map, the inclusions, the plan and the probe as messages the app draws natively.

Runs beside the Foxglove bridge (``viz:=true`` on the scan launch files), reading what any subscriber may read and
publishing Foxglove's well-known schemas (messages/foxglove.py) in the ``phantom`` frame (metres; palpa's mm / 1000):

| topic | type | what |
|---|---|---|
| ``viz/map`` | foxglove.Grid | the stiffness map, field ``stiffness`` (NaN: no data), for the 3D panel (latched) |
| ``viz/map_image`` | foxglove.RawImage | the map in viridis like map.png, north up, with its colour bar (latched) |
| ``viz/map_annotations`` | foxglove.ImageAnnotations | the colour bar's range and the inclusions, over the image (latched) |
| ``viz/inclusions`` | foxglove.SceneUpdate | each inclusion as a flat disc with a label (latched) |
| ``viz/plan`` | foxglove.SceneUpdate | the scan plan as a line strip and the region as a loop (latched) |
| ``viz/tf`` | foxglove.FrameTransform | ``phantom`` -> ``probe`` from ``robot/pose`` |

Force, heights and stiffness need no view: the bridge sends ``pressure/state``, ``probe/heights`` and
``stiffness/sample`` as JSON, which the Plot panel reads directly (docs/foxglove-layout.json plots them).
"""

from __future__ import annotations

from functools import cache

import numpy as np

import palpa
from messages import Inclusions, RobotPose, ScanPlan, StiffnessMap
from messages.foxglove import (
    FLOAT32,
    LINE_LOOP,
    LINE_STRIP,
    CircleAnnotation,
    Color,
    CylinderPrimitive,
    FrameTransform,
    Grid,
    ImageAnnotations,
    LinePrimitive,
    PackedElementField,
    Point2,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneEntityDeletion,
    SceneUpdate,
    TextAnnotation,
    TextPrimitive,
    Time,
    Vector2,
    Vector3,
)
from models.stiffness_map import fill_gaps

MM = 1e-3
FRAME = "phantom"
PROBE_FRAME = "probe"
RED = Color(r=0.9, g=0.1, b=0.1, a=1.0)
WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)
CLEAR = Color(r=0.0, g=0.0, b=0.0, a=0.6)
NO_DATA_RGB = (90, 90, 90)
BAR_GAP_PX, BAR_WIDTH_PX = 6, 16


@cache
def viridis_lut() -> np.ndarray:
    """256 x 3 uint8: matplotlib's viridis, the colour map of map.png."""
    import matplotlib

    return (matplotlib.colormaps["viridis"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(np.uint8)


class ScanViewsParams(palpa.Params):
    image_width_px: int = 240
    """Approximate width of the map image (cells are drawn as squares of a whole number of pixels)."""


class ScanViews(palpa.Node):
    """Converts map, inclusions, plan and pose into Foxglove schemas (see the module docstring)."""

    Params = ScanViewsParams
    params: ScanViewsParams

    def setup(self) -> None:
        self.grid_pub = self.publisher("viz/map", Grid, latched=True)
        self.image_pub = self.publisher("viz/map_image", RawImage, latched=True)
        self.notes_pub = self.publisher("viz/map_annotations", ImageAnnotations, latched=True)
        self.inc_pub = self.publisher("viz/inclusions", SceneUpdate, latched=True)
        self.plan_pub = self.publisher("viz/plan", SceneUpdate, latched=True)
        self.tf_pub = self.publisher("viz/tf", FrameTransform)
        self.map: StiffnessMap | None = None
        self.inclusions: Inclusions | None = None
        self.subscribe("map/stiffness", self.on_map)
        self.subscribe("map/inclusions", self.on_inclusions)
        self.subscribe("robot/plan", self.on_plan)
        self.subscribe("robot/pose", self.on_pose)

    # -- the map ---------------------------------------------------------------------------------------------
    def on_map(self, m: StiffnessMap) -> None:
        nx, ny = len(m.x_mm), len(m.y_mm)
        if nx < 1 or ny < 1 or len(m.stiffness) != nx * ny:
            self.log.warning("map/stiffness: %d values for a %d x %d grid; not drawn", len(m.stiffness), nx, ny)
            return
        self.map = m
        res = (m.x_mm[1] - m.x_mm[0]) if nx > 1 else ((m.y_mm[1] - m.y_mm[0]) if ny > 1 else 1.0)
        values = np.asarray(m.stiffness, dtype="<f4")
        corner = Vector3(x=(m.x_mm[0] - res / 2) * MM, y=(m.y_mm[0] - res / 2) * MM, z=0.0)
        self.grid_pub.publish(Grid(
            timestamp=Time.of(m.stamp_ns), frame_id=FRAME, pose=Pose(position=corner), column_count=nx,
            cell_size=Vector2(x=res * MM, y=res * MM), row_stride=nx * 4, cell_stride=4,
            fields=[PackedElementField(name="stiffness", offset=0, type=FLOAT32)], data=values.tobytes()))
        self.image_pub.publish(self._image(m, nx, ny))
        self._annotate()

    def _scale(self, nx: int) -> int:
        return max(1, int(self.params.image_width_px) // nx)

    def _image(self, m: StiffnessMap, nx: int, ny: int) -> RawImage:
        k = self._scale(nx)
        grid = fill_gaps(np.asarray(m.stiffness, dtype=float).reshape(ny, nx))
        lo, hi = _range(grid)
        idx = np.clip(((grid - lo) / (hi - lo) * 255).round(), 0, 255)
        rgb = viridis_lut()[np.nan_to_num(idx).astype(np.intp)]
        rgb[~np.isfinite(grid)] = NO_DATA_RGB
        rgb = np.repeat(np.repeat(rgb[::-1], k, axis=0), k, axis=1)  # row 0 of an image is its top: max y
        h = ny * k
        bar = viridis_lut()[np.linspace(255, 0, h).round().astype(np.intp)][:, None, :].repeat(BAR_WIDTH_PX, 1)
        gap = np.zeros((h, BAR_GAP_PX, 3), dtype=np.uint8)
        img = np.ascontiguousarray(np.concatenate([rgb, gap, bar], axis=1))
        return RawImage(timestamp=Time.of(m.stamp_ns), frame_id=FRAME, width=img.shape[1], height=h,
                        encoding="rgb8", step=img.shape[1] * 3, data=img.tobytes())

    def on_inclusions(self, inc: Inclusions) -> None:
        self.inclusions = inc
        t = Time.of(inc.stamp_ns)
        entities = []
        for i, d in enumerate(inc.inclusions, 1):
            centre = Vector3(x=d.x_mm * MM, y=d.y_mm * MM, z=0.5 * MM)
            entities.append(SceneEntity(
                timestamp=t, frame_id=FRAME, id=f"inclusion-{i}",
                metadata=[{"key": "contrast", "value": f"{d.contrast:.2f}"},
                          {"key": "radius_mm", "value": f"{d.radius_mm:.1f}"}],
                cylinders=[CylinderPrimitive(pose=Pose(position=centre), color=Color(r=0.9, g=0.1, b=0.1, a=0.4),
                                             size=Vector3(x=2 * d.radius_mm * MM, y=2 * d.radius_mm * MM, z=MM))],
                texts=[TextPrimitive(pose=Pose(position=Vector3(x=centre.x, y=centre.y, z=3 * MM)), font_size=14,
                                     color=RED, text=f"{i}: x{d.contrast:.1f}, r {d.radius_mm:.1f} mm")]))
        self.inc_pub.publish(SceneUpdate(deletions=[SceneEntityDeletion(timestamp=t, type=1)], entities=entities))
        self._annotate()

    def _annotate(self) -> None:
        """The colour bar's range and the inclusions, in the map image's pixels."""
        m = self.map
        if m is None:
            return
        nx, ny = len(m.x_mm), len(m.y_mm)
        k = self._scale(nx)
        res = (m.x_mm[1] - m.x_mm[0]) if nx > 1 else 1.0
        lo, hi = _range(fill_gaps(np.asarray(m.stiffness, dtype=float).reshape(ny, nx)))
        t = Time.of(m.stamp_ns)
        bar_x = nx * k + BAR_GAP_PX
        texts = [TextAnnotation(timestamp=t, position=Point2(x=bar_x - 60, y=y), text=f"{v:.4g} {m.unit}",
                                font_size=11, text_color=WHITE, background_color=CLEAR)
                 for v, y in ((hi, 12.0), (lo, ny * k - 4.0))]
        circles = []
        for i, d in enumerate(self.inclusions.inclusions if self.inclusions else [], 1):
            px = (d.x_mm - (m.x_mm[0] - res / 2)) / res * k
            py = ((m.y_mm[-1] + res / 2) - d.y_mm) / res * k
            circles.append(CircleAnnotation(timestamp=t, position=Point2(x=px, y=py), diameter=2 * d.radius_mm / res * k,
                                            thickness=2, fill_color=Color(r=0, g=0, b=0, a=0), outline_color=RED))
            texts.append(TextAnnotation(timestamp=t, position=Point2(x=px, y=py), text=str(i), font_size=11,
                                        text_color=RED, background_color=Color(r=0, g=0, b=0, a=0)))
        self.notes_pub.publish(ImageAnnotations(circles=circles, texts=texts))

    # -- the plan and the probe ------------------------------------------------------------------------------
    def on_plan(self, plan: ScanPlan) -> None:
        t = Time.of(plan.stamp_ns)
        origin = Pose(position=Vector3(x=0, y=0, z=0))
        path = [Vector3(x=w.x_mm * MM, y=w.y_mm * MM, z=w.z_mm * MM) for w in plan.waypoints]
        x0, y0, x1, y1 = plan.region_mm
        region = [Vector3(x=x * MM, y=y * MM, z=0.0) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
        lines = [LinePrimitive(type=LINE_LOOP, pose=origin, thickness=2, scale_invariant=True, points=region,
                               color=Color(r=0.6, g=0.6, b=0.6, a=1.0))]
        if len(path) >= 2:
            lines.append(LinePrimitive(type=LINE_STRIP, pose=origin, thickness=1.5, scale_invariant=True,
                                       points=path, color=Color(r=0.2, g=0.5, b=1.0, a=1.0)))
        self.plan_pub.publish(SceneUpdate(
            deletions=[SceneEntityDeletion(timestamp=t, type=1)],
            entities=[SceneEntity(timestamp=t, frame_id=FRAME, id="plan", lines=lines,
                                  metadata=[{"key": "mode", "value": plan.mode},
                                            {"key": "lines", "value": str(plan.lines)}])]))

    def on_pose(self, p: RobotPose) -> None:
        self.tf_pub.publish(FrameTransform(
            timestamp=Time.of(p.stamp_ns), parent_frame_id=FRAME, child_frame_id=PROBE_FRAME,
            translation=Vector3(x=p.x_mm * MM, y=p.y_mm * MM, z=p.z_mm * MM),
            rotation=rotation_vector_quaternion(p.rx_rad, p.ry_rad, p.rz_rad)))


def rotation_vector_quaternion(rx: float, ry: float, rz: float) -> Quaternion:
    """The unit quaternion of a rotation vector (axis times angle, rad), as a UR pose carries its rotation."""
    angle = float(np.sqrt(rx * rx + ry * ry + rz * rz))
    if angle < 1e-12:
        return Quaternion()
    s = float(np.sin(angle / 2)) / angle
    return Quaternion(x=rx * s, y=ry * s, z=rz * s, w=float(np.cos(angle / 2)))


def _range(grid: np.ndarray) -> tuple[float, float]:
    finite = grid[np.isfinite(grid)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


if __name__ == "__main__":
    palpa.run_node(ScanViews)
