"""The scan views for Foxglove (nodes/mapping/foxglove_views.py) and the launch file's ``viz:`` section and ``if:``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from messages import Inclusions, RobotPose, ScanPlan, StiffnessMap
from messages.foxglove import FrameTransform, Grid, ImageAnnotations, RawImage, SceneUpdate
from messages.robot import PlanWaypoint
from messages.stiffness import DetectedInclusion
from nodes.mapping.foxglove_views import ScanViews, viridis_lut
from palpa.errors import LaunchError
from palpa.launch import load_launch
from palpa.testing import NodeHarness

# 3 columns (x = 10, 12, 14 mm) x 2 rows (y = 20, 22 mm); one cell without data
MAP = StiffnessMap(stamp_ns=3_000_000_007, unit="kPa", x_mm=[10.0, 12.0, 14.0], y_mm=[20.0, 22.0],
                   stiffness=[20.0, 30.0, 40.0, 60.0, math.nan, 50.0], count=[1, 1, 1, 1, 0, 1],
                   spread=[0.0] * 6, samples=5)


def test_the_map_becomes_a_grid_in_metres_and_an_image_with_its_colour_bar() -> None:
    with NodeHarness(ScanViews, {"image_width_px": 30}) as h:
        h.publish("map/stiffness", MAP)
        (grid,) = h.published("viz/map", Grid)
        assert (grid.column_count, grid.cell_stride, grid.row_stride) == (3, 4, 12)
        assert grid.timestamp.sec == 3 and grid.timestamp.nsec == 7
        assert grid.cell_size.x == pytest.approx(0.002)
        assert (grid.pose.position.x, grid.pose.position.y) == pytest.approx((0.009, 0.019))  # the corner
        np.testing.assert_array_equal(np.frombuffer(grid.data, "<f4"), np.array(MAP.stiffness, "f4"))
        (img,) = h.published("viz/map_image", RawImage)
        k = 10  # 30 px / 3 columns
        assert (img.height, img.width, img.encoding, img.step) == (2 * k, 3 * k + 22, "rgb8", (3 * k + 22) * 3)
        px = np.frombuffer(img.data, np.uint8).reshape(img.height, img.width, 3)
        lut = viridis_lut()
        assert tuple(px[0, 0]) == tuple(lut[255])  # top left: y = 22, x = 10, the stiffest (60)
        assert tuple(px[-1, 0]) == tuple(lut[0])  # bottom left: y = 20, x = 10, the softest (20)
        assert tuple(px[0, k]) == tuple(lut[128])  # (12, 22): no data, drawn as its neighbours' median (40) as
        # map.png does; the grid keeps the NaN
        assert tuple(px[0, -1]) == tuple(lut[255]) and tuple(px[-1, -1]) == tuple(lut[0])  # the bar
        (notes,) = h.published("viz/map_annotations", ImageAnnotations)
        assert [t.text for t in notes.texts] == ["60 kPa", "20 kPa"]


def test_inclusions_are_labelled_discs_and_circles_on_the_image() -> None:
    with NodeHarness(ScanViews, {"image_width_px": 30}) as h:
        h.publish("map/stiffness", MAP)
        h.publish("map/inclusions", Inclusions(stamp_ns=1, unit="kPa", baseline=20.0, inclusions=[
            DetectedInclusion(x_mm=12.0, y_mm=20.5, radius_mm=1.0, contrast=2.5)]))
        (scene,) = h.published("viz/inclusions", SceneUpdate)
        assert scene.deletions[0].type == 1  # the previous set goes
        (e,) = scene.entities
        (disc,) = e.cylinders
        assert (disc.pose.position.x, disc.pose.position.y) == pytest.approx((0.012, 0.0205))
        assert disc.size.x == pytest.approx(0.002)
        assert "x2.5" in e.texts[0].text
        notes = h.published("viz/map_annotations", ImageAnnotations)[-1]
        (circle,) = notes.circles
        # x: 3 mm from the left edge (9 mm) = 1.5 cells; y: 2.5 mm below the top edge (23 mm) = 1.25 cells (the
        # image's rows run down from max y); 10 px a cell
        assert (circle.position.x, circle.position.y, circle.diameter) == pytest.approx((15.0, 12.5, 10.0))


def test_the_plan_is_a_line_strip_and_the_probe_a_frame() -> None:
    plan = ScanPlan(stamp_ns=1, mode="sweep", region_mm=(0.0, 0.0, 10.0, 5.0), spacing_mm=5.0, speed_mm_s=10.0,
                    lines=1, estimated_duration_s=1.0, waypoints=[
                        PlanWaypoint(x_mm=0.0, y_mm=0.0, z_mm=5.0, speed_mm_s=10.0, kind="contact", line=0),
                        PlanWaypoint(x_mm=10.0, y_mm=5.0, z_mm=5.0, speed_mm_s=10.0, kind="contact", line=0)])
    with NodeHarness(ScanViews) as h:
        h.publish("robot/plan", plan)
        (scene,) = h.published("viz/plan", SceneUpdate)
        loop, strip = scene.entities[0].lines
        assert [c for p in loop.points for c in (p.x, p.y)] == pytest.approx([0, 0, 0.01, 0, 0.01, 0.005, 0, 0.005])
        assert [c for p in strip.points for c in (p.x, p.y, p.z)] == pytest.approx([0, 0, 0.005, 0.01, 0.005, 0.005])
        h.publish("robot/pose", RobotPose(stamp_ns=2, x_mm=1.0, y_mm=2.0, z_mm=3.0, ry_rad=math.pi))
        (tf,) = h.published("viz/tf", FrameTransform)
        assert (tf.parent_frame_id, tf.child_frame_id) == ("phantom", "probe")
        assert (tf.translation.x, tf.translation.y, tf.translation.z) == pytest.approx((0.001, 0.002, 0.003))
        q = tf.rotation  # half a turn about y (a probe pointing down, as the UR's rotation vector says)
        assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 1.0, 0.0, 0.0), abs=1e-12)


LAUNCH = """
args:
  - {name: viz, default: false}
viz: VIZ
nodes:
  - {name: a, node: nodes.demo:Talker}
  - {name: b, node: nodes.demo:Listener, if: $(arg viz)}
"""


def plan_of(tmp_path: Path, section: str, **args: object) -> list[str]:
    f = tmp_path / "g.yaml"
    f.write_text(LAUNCH.replace("VIZ", section))
    return [n.name for n in load_launch(f, dict(args), run_dir=tmp_path / "run").nodes]


def test_launch_viz_section_and_node_conditions(tmp_path: Path) -> None:
    assert plan_of(tmp_path, "{enabled: $(arg viz)}") == ["a"]
    assert plan_of(tmp_path, "{enabled: $(arg viz), port: 0}", viz=True) == ["viz", "a", "b"]
    f = tmp_path / "g.yaml"
    f.write_text(LAUNCH.replace("VIZ", "{port: 0, client_publish: [robot/estop]}"))
    viz = load_launch(f, {}, run_dir=tmp_path / "run").nodes[0]
    assert (viz.target, viz.params["port"], viz.params["client_publish"]) == (
        "palpa.viz.bridge:Bridge", 0, ["robot/estop"])
    with pytest.raises(LaunchError, match=r"g\.yaml:4:\d+: viz host '0\.0\.0\.0' is beyond loopback"):
        plan_of(tmp_path, "{host: 0.0.0.0}")
    assert plan_of(tmp_path, "{host: 0.0.0.0, allow_remote: true}")[0] == "viz"


def test_the_shipped_layout_opens_panels_on_topics_that_exist() -> None:
    layout = json.loads((Path(__file__).parent.parent / "docs" / "foxglove-layout.json").read_text())
    ids: list[str] = []

    def walk(node: object) -> None:
        if isinstance(node, str):
            ids.append(node)
        elif isinstance(node, dict):
            walk(node["first"])
            walk(node["second"])

    walk(layout["layout"])
    assert sorted(ids) == sorted(layout["configById"])
    h = NodeHarness(ScanViews)
    views = {p.topic for p in h.node._inventory.pubs.values()}
    h.close()
    three_d = layout["configById"]["3D!palpa-scan"]
    assert set(three_d["topics"]) <= views and three_d["followTf"] == "phantom"
    assert layout["configById"]["Image!palpa-map"]["imageMode"]["imageTopic"] in views
    assert layout["configById"]["Publish!palpa-estop"]["topicName"] == "robot/estop"
