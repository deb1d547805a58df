"""Issue 15: the plan comes from what the arm finds. Surface fits, rasters over a surface, the region from the
specimen, refusals before motion, and the scanner's touch-off on the simulated arm (mock clock, in process)."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import palpa
from messages import IndenterDisplacements, ProbeHeights
from models.raster import indent_raster, sweep_raster
from models.surface import (
    SpecimenDoesNotFit,
    check_fits,
    fit_surface,
    region_in_footprint,
    touch_points,
)
from nodes.scanner.robot_scanner import RobotScanner
from palpa.testing import NodeHarness

REPO = Path(__file__).resolve().parent.parent
BOX = (-10.0, -10.0, 0.5, 70.0, 70.0, 60.0)


def dome(x: float, y: float) -> float:
    """A dome along y over 0..50 mm: 6 mm on the centre line, 3 mm at the edges."""
    u = (y - 25.0) / 25.0
    return 3.0 + 3.0 * (1 - u * u)


def test_a_grid_of_touches_fits_a_dome_exactly_and_corners_and_centre_fit_a_plane() -> None:
    pts = [(x, y, dome(x, y)) for x, y in touch_points((4, 4, 76, 46), 3)]
    fit = fit_surface(pts)
    assert fit.model == "quadratic" and fit.rms_mm < 1e-9
    for x, y in [(10, 10), (40, 25), (70, 44), (4, 4)]:
        assert fit.z(x, y) == pytest.approx(dome(x, y), abs=1e-9)
    five = touch_points((0, 0, 10, 20), 2)
    assert five == [(0, 0), (10, 0), (5, 10), (10, 20), (0, 20)]
    tilted = fit_surface([(x, y, 2 + 0.1 * x - 0.05 * y) for x, y in five])
    assert tilted.model == "plane" and tilted.z(3, 7) == pytest.approx(2 + 0.3 - 0.35)
    with pytest.raises(ValueError, match="cannot define"):
        fit_surface([(0, 0, 1), (1, 0, 1), (2, 0, 1)])  # all on one line


def test_the_region_is_the_footprint_less_the_margin_and_a_misfit_names_the_box_and_the_extent() -> None:
    assert region_in_footprint((0, 0, 80, 50), 4) == (4, 4, 76, 46)
    with pytest.raises(ValueError, match="smaller than twice the 6 mm edge margin"):
        region_in_footprint((0, 0, 10, 30), 6)
    check_fits((4, 4, 66, 46), BOX, top_mm=20, clearance_mm=15)
    with pytest.raises(SpecimenDoesNotFit, match=r"x 4\.\.96, y 4\.\.46 mm does not fit the workspace box \(x -10\.\.70, "
                                                 r"y -10\.\.70, z 0\.5\.\.60 mm\): x 96 > x_max 70"):
        check_fits((4, 4, 96, 46), BOX)
    with pytest.raises(SpecimenDoesNotFit, match=r"surface up to z 40\.0 mm plus the 25 mm .* z_max 60"):
        check_fits((4, 4, 66, 46), BOX, top_mm=40, clearance_mm=25)


def test_a_sweep_over_a_surface_keeps_the_working_offset_and_a_flat_one_adds_no_points() -> None:
    plan = sweep_raster(4, 4, 76, 46, spacing_mm=6, speed_mm_s=20, contact_z_mm=1.0, surface=dome, axis="y")
    contact = [w for w in plan.waypoints if w.kind == "contact"]
    assert len(contact) > 13 * 10  # each line follows the dome point by point
    assert max(abs(w.z_mm - dome(w.x_mm, w.y_mm) - 1.0) for w in contact) < 1e-9
    top = max(dome(4, y) for y in range(4, 47))
    assert all(w.z_mm == pytest.approx(top + 1.0 + 20.0, abs=0.01) for w in plan.waypoints if w.kind in ("transit", "retract"))
    flat = sweep_raster(4, 4, 76, 46, spacing_mm=6, speed_mm_s=20, contact_z_mm=1.0, surface=lambda x, y: 10.0)
    assert len([w for w in flat.waypoints if w.kind == "contact"]) == 2 * flat.line_count
    presses = indent_raster(4, 4, 76, 46, spacing_mm=8, contact_z_mm=0.0, depth_mm=2.0, hold_s=0.1, surface=dome)
    assert all(w.z_mm == pytest.approx(dome(w.x_mm, w.y_mm) - 2.0) for w in presses.waypoints if w.kind == "hold")


def write_geometry(tmp_path: Path, footprint: list[float], thickness: float = 6.0) -> str:
    f = tmp_path / "geometry.yaml"
    f.write_text(f"thickness_mm: {thickness}\nfootprint_mm: {footprint}\n")
    return str(f)


def touch_params(geometry: str, **kw: Any) -> dict[str, Any]:
    return {"geometry": geometry, "touchoff": "heights", "spacing_mm": 8, "speed_mm_s": 20, "home_mm": [5, 5, 30],
            "edge_margin_mm": 4.0, "watchdog_s": 0.5, **kw}


def probe_over(h: NodeHarness[RobotScanner], surface: Any, stroke: float = 10.0) -> None:
    """A probe whose three SPS read the gap between the face and ``surface`` under it (clipped to the stroke)."""
    x, y, z = h.node.driver.state().pose[:3]
    gap = min(max(z - surface(x, y), 0.0), stroke)
    h.publish("probe/heights", ProbeHeights(stamp_ns=h.clock.now_ns(), seq=0, h_mm=(gap, gap, gap, stroke),
                                            raw=(0, 0, 0, 0), d_in_mm=0.0, tilt_rad=0.0))


def run_until_plan(h: NodeHarness[RobotScanner], surface: Any, seconds: float = 120.0) -> None:
    for _ in range(int(seconds / 0.004)):
        probe_over(h, surface)
        h.advance(0.004)
        if len(h.published("robot/plan")) > 1 or h.node.state == "fault":
            return


def test_the_scanner_touches_off_and_sweeps_at_the_working_offset_over_the_dome(tmp_path: Path) -> None:
    h = NodeHarness(RobotScanner, touch_params(write_geometry(tmp_path, [0, 0, 80, 50]),
                                               workspace_mm=[-10, -10, 0.5, 100, 100, 60]))
    assert h.published("robot/plan")[0].region_mm == (4, 4, 76, 46)  # the footprint less the margin
    run_until_plan(h, dome)
    assert h.node.state == "scanning", h.node.message
    touches = h.node.specimen.touch.touches  # type: ignore[union-attr]
    assert len(touches) == 9 and max(abs(z - dome(x, y)) for x, y, z in touches) < 0.05
    plan = h.published("robot/plan")[-1]
    sliding = [w for w in plan.waypoints if w.kind == "contact"]
    assert max(abs(w.z_mm - dome(w.x_mm, w.y_mm) - 1.0) for w in sliding) < 0.1  # working offset 1 mm


def test_nothing_under_a_touch_point_is_a_fault_naming_it(tmp_path: Path) -> None:
    h = NodeHarness(RobotScanner, touch_params(write_geometry(tmp_path, [0, 0, 30, 30], 2.0)))
    run_until_plan(h, lambda x, y: 0.0 if x > 20 else 2.0)  # the specimen ends before the region does
    assert h.node.state == "fault"
    assert re.search(r"found no specimen at \(26, 4\) mm: the surface there is at z 0\.00 mm, below the floor 0\.5",
                     h.node.message), h.node.message


def test_a_specimen_too_big_for_the_box_is_refused_before_motion_with_the_numbers(tmp_path: Path) -> None:
    geo = write_geometry(tmp_path, [0, 0, 100, 50])
    with pytest.raises(palpa.ParamError, match=r"refusing the specimen before any motion: the specimen's footprint "
                                               r"x 0\.\.100, y 0\.\.50 mm less the 4 mm edge margin, x 4\.\.96, y "
                                               r"4\.\.46 mm does not fit the workspace box \(x -10\.\.70, y -10\.\.70, "
                                               r"z 0\.5\.\.60 mm\): x 96 > x_max 70"):
        NodeHarness(RobotScanner, touch_params(geo))
    tall = write_geometry(tmp_path, [0, 0, 50, 50], 55.0)
    with pytest.raises(palpa.ParamError, match=r"surface up to z 55\.0 mm plus the 8 mm .* z_max 60"):
        NodeHarness(RobotScanner, touch_params(tall))


@pytest.mark.parametrize(("surface", "press_z"), [(11.0, 6.0), (4.0, 4.0 - 0.6 * 4.0)], ids=["deep", "thin"])
def test_the_camera_probe_presses_the_set_depth_below_the_surface_it_found(tmp_path: Path, surface: float,
                                                                           press_z: float) -> None:
    """The set depth (5 mm) below the found surface; on a thin specimen never more than 0.6 of its thickness."""
    geo = write_geometry(tmp_path, [0, 0, 40, 40], 12.0)  # the measurement said 12: the touch-off finds the real one
    h = NodeHarness(RobotScanner, touch_params(geo, touchoff="indenters", mode="indent", watch_topic="camera/indenters",
                                              indent_depth_mm=5.0, hold_s=0.1, touch_grid=2))
    for _ in range(int(60 / 0.004)):
        x, y, z = h.node.driver.state().pose[:3]
        d = max(0.0, surface - z) * 0.5
        h.publish("camera/indenters", IndenterDisplacements(stamp_ns=h.clock.now_ns(), frame_seq=0,
                                                            displacement_mm=(d, d, d, d), centroid_x_px=(0, 0, 0, 0),
                                                            centroid_y_px=(0, 0, 0, 0), valid=(True,) * 4))
        h.advance(0.004)
        if len(h.published("robot/plan")) > 1 or h.node.state == "fault":
            break
    holds = [w for w in h.published("robot/plan")[-1].waypoints if w.kind == "hold"]
    assert holds and all(w.z_mm == pytest.approx(press_z, abs=0.1) for w in holds)
    assert not math.isnan(holds[0].z_mm)





@pytest.mark.system
def test_the_launch_refuses_a_specimen_wider_than_the_box_before_any_motion(tmp_path: Path) -> None:
    """The one launch-level check: phantom:= alone, the sim measurer's footprint (the launch's prepare step), the
    scanner's refusal naming the box and the extent, the launch's exit code 2, and no plan ever published (nothing
    moved). Composed (`--in-process`): the refusal is the scanner's, however the nodes are run; a node process's
    exit code 2 on a ParamError and the launcher ending with a required node's code are tested in
    tests/test_transport_options.py and tests/test_launch_supervisor.py."""
    run = subprocess.run(
        [sys.executable, "-m", "palpa.cli.main", "launch", str(REPO / "launch" / "scan_sim.yaml"), "--in-process",
         f"phantom:={REPO / 'phantoms' / 'specimens' / 'too_wide_200x40.yaml'}", "--run-dir", str(tmp_path / "run"),
         "--no-progress"], capture_output=True, text=True, timeout=120, check=False)
    text = run.stdout + run.stderr
    assert run.returncode == 2, text  # a node that cannot start (ParamError)
    assert re.search(r"refusing the specimen before any motion: the specimen's footprint x -?\d+(\.5)?\.\.20\d(\.5)?, "
                     r"y .* mm less the 6 mm edge margin, x .* does not fit the workspace box \(x -10\.\.150, y "
                     r"-10\.\.150, z 0\.5\.\.100 mm\): x 19\d(\.5)? > x_max 150", text), text
    assert "plan:" not in text
def test_an_indenter_held_in_by_guide_friction_after_a_press_does_not_count_as_contact(tmp_path: Path) -> None:
    """After each press the indenters stay up to 0.14 mm in (Coulomb friction in their guides, as the sim probe
    is built): the next point's descent starts from that offset (a quarter of the 0.3 mm threshold is below it:
    untared, the whole descent is 'rising'), and the surface is still where contact began, not 0.35 mm lower
    where the held-in indenters begin to slide again."""
    geo = write_geometry(tmp_path, [0, 0, 40, 40], 12.0)
    h = NodeHarness(RobotScanner, touch_params(geo, touchoff="indenters", mode="indent", watch_topic="camera/indenters",
                                              indent_depth_mm=5.0, hold_s=0.1, touch_grid=2))
    surface, gain, hold = 10.0, (0.4, 0.4, 0.2, 0.4), (0.14, 0.1, 0.02, 0.12)  # per indenter: soft, soft, hard, soft
    stuck = [0.0] * 4
    for _ in range(int(60 / 0.004)):
        z = h.node.driver.state().pose[2]
        press = [max(0.0, surface - z) * g for g in gain]
        stuck = [max(s, min(p, f)) for s, p, f in zip(stuck, press, hold, strict=True)]  # held in, never released
        d = [max(p, s) for p, s in zip(press, stuck, strict=True)]  # slides back along its free line
        h.publish("camera/indenters", IndenterDisplacements(stamp_ns=h.clock.now_ns(), frame_seq=0,
                                                            displacement_mm=(d[0], d[1], d[2], d[3]),
                                                            centroid_x_px=(0, 0, 0, 0), centroid_y_px=(0, 0, 0, 0),
                                                            valid=(True,) * 4))
        h.advance(0.004)
        if len(h.published("robot/plan")) > 1 or h.node.state == "fault":
            break
    touch = h.node.specimen.touch
    assert touch is not None and touch.done, h.node.message
    assert len(touch.touches) == 5 and [round(z, 1) for _, _, z in touch.touches] == [surface] * 5


def test_the_table_touch_finds_the_table_beside_the_specimen_first_and_publishes_its_height(tmp_path: Path) -> None:
    """``table_point_mm``: before the touch-off the SPS read the table beside the specimen (here 0.3 mm below the
    frame's z = 0, a registration that much high), latched on ``scanner/table``; the specimen's touches and the
    plan are as without it."""
    def world(x: float, y: float) -> float:
        return dome(x, y) if 0 <= x <= 80 and 0 <= y <= 50 else -0.3

    h = NodeHarness(RobotScanner, touch_params(write_geometry(tmp_path, [0, 0, 80, 50]), table_point_mm=[-8, 25],
                                               workspace_mm=[-10, -10, 0.5, 100, 100, 60]))
    run_until_plan(h, world)
    assert h.node.state == "scanning", h.node.message
    (table,) = h.published("scanner/table")
    assert (table.x_mm, table.y_mm) == (-8, 25) and abs(table.z_mm + 0.3) < 0.05
    touches = h.node.specimen.touch.touches  # type: ignore[union-attr]
    assert len(touches) == 9 and max(abs(z - dome(x, y)) for x, y, z in touches) < 0.05


def test_no_table_under_the_table_point_is_a_fault_naming_it(tmp_path: Path) -> None:
    h = NodeHarness(RobotScanner, touch_params(write_geometry(tmp_path, [0, 0, 80, 50]), table_point_mm=[-8, 25],
                                               workspace_mm=[-10, -10, 0.5, 100, 100, 60]))
    run_until_plan(h, lambda x, y: dome(x, y) if x >= 0 else -30.0)  # the table's edge: nothing within the SPS' reach
    assert h.node.state == "fault" and not h.published("scanner/table")
    assert "the table touch at (-8, 25) mm found no bare table" in h.node.message, h.node.message


def test_a_table_point_the_arm_may_not_reach_or_on_the_specimen_is_refused_before_motion(tmp_path: Path) -> None:
    geo = write_geometry(tmp_path, [0, 0, 50, 50])
    with pytest.raises(palpa.ParamError, match=r"refusing the table touch before any motion: table_point_mm "
                                               r"\(-15, 25\) mm lies outside the workspace box \(x -10\.\.70, "
                                               r"y -10\.\.70 mm\): the arm may not go there"):
        NodeHarness(RobotScanner, touch_params(geo, table_point_mm=[-15, 25]))
    with pytest.raises(palpa.ParamError, match=r"table_point_mm \(-4, 25\) mm is 4\.0 mm from the specimen \(x 0\.\.50, "
                                               r"y 0\.\.50 mm\); the SPS ring needs 7 mm of bare table"):
        NodeHarness(RobotScanner, touch_params(geo, table_point_mm=[-4, 25]))
    with pytest.raises(palpa.ParamError, match=r"table_point_mm needs touchoff: heights .* touchoff is force"):
        NodeHarness(RobotScanner, touch_params(geo, table_point_mm=[-8, 25], touchoff="force"))
    with pytest.raises(palpa.ParamError, match=r"table_point_mm needs x, y"):
        NodeHarness(RobotScanner, touch_params(geo, table_point_mm=[-8]))
