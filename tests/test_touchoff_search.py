"""Issue 15, the region from a touch-off search: given only a box, the scanner touches down on a grid inside it
(contact or none, by the air-float probe's own heights), and plans the region from the extent where it found the
specimen less the edge margin. On a phantom smaller than the box, in process on the sim arm and through ur_rtde
against the UR emulator."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pytest

from emulators.clock_file import ClockWriter
from models.surface import region_from_touches, search_points
from nodes.probe.fibre_reader import FibreReader
from nodes.probe.pressure_controller import PressureController
from nodes.scanner.robot_scanner import RobotScanner
from palpa.testing import GraphHarness
from palpa.timing.clock import MockClock
from tests.followed_clock import FollowedClock
from tests.procs import ur_emulator

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

SMALL = "phantoms/specimens/small_40x30_8mm.yaml"  # 40 x 30 mm, 8 mm thick, at the origin of the phantom frame
BOX = [-10.0, -6.0, 0.5, 50.0, 36.0, 16.0]  # 60 x 42 mm of table around it, searched from 16 mm down
STEP = 14.0
"""A 6 x 4 grid: x -10, 2, 14, 26, 38, 50 and y -6, 8, 22, 36. Four points have the whole ring 2 mm or more inside the
edges, four (x 2 and 38) hang half over one (a miss by the SPS's own spread), the rest see only the table."""
RING = 6.0  # the SPS ring's radius: a point counts only with the whole ring on the specimen


def test_search_points_cover_the_box_and_the_region_is_the_touched_extent_less_the_margin() -> None:
    pts = search_points((0, 0, 20, 10), 10)
    assert pts == [(0, 0), (10, 0), (20, 0), (20, 10), (10, 10), (0, 10)]
    assert len(search_points((0, 0, 25, 10), 10)) == 4 * 2  # at most step apart: 25 mm in 3 steps
    touches = [(10.0, 10.0, 8.0), (20.0, 10.0, 8.0), (20.0, 20.0, 8.1), (10.0, 20.0, 7.9)]
    assert region_from_touches(touches, 2.0) == (12.0, 12.0, 18.0, 18.0)
    with pytest.raises(ValueError, match=r"found no specimen in the searched box x 0\.\.60, y 0\.\.50 mm"):
        region_from_touches([], 2.0, (0, 0, 60, 50))
    with pytest.raises(ValueError, match=r"only at x 10\.\.20, y 10\.\.10 mm.*twice the 2 mm edge margin"):
        region_from_touches(touches[:2], 2.0)


def search(driver: dict[str, Any], timeout_s: float, clock: ClockWriter | None = None) -> RobotScanner:
    """The scanner with the sim probe over SMALL, given only BOX; returns it once the raster's plan is out. With
    ``clock`` (a real-time driver, the UR emulator following it: ``--clock-file``) the harness runs on a
    tests.followed_clock.FollowedClock, so that a stall of this process holds the arm instead of letting it run on
    unread; else by 50 ms of simulated time."""
    g = GraphHarness(clock=MockClock(time.time_ns()) if clock is not None else None)
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 36.0, "sim_tracking_kpa": 0.0})
    g.add(FibreReader, {"phantom": SMALL, "sim_errors": "ideal", "poll_hz": 100.0})
    scanner = g.add(RobotScanner, {
        "search_box_mm": BOX, "search_step_mm": STEP, "edge_margin_mm": 2.0, "touchoff": "heights",
        "search_speed_mm_s": 20.0, "transit_speed_mm_s": 45.0, "spacing_mm": 4.0, "home_mm": [0, 0, 16],
        "watchdog_s": 0.5, **driver})
    deadline = time.monotonic() + timeout_s
    followed = FollowedClock(clock, g.advance) if clock is not None else None
    while time.monotonic() < deadline and len(g.published("robot/plan")) < 2 and scanner.state != "fault":
        if followed is not None:
            followed.tick()
        else:
            g.advance(0.05)
    if clock is not None:
        clock.release()  # the driver's teardown waits for the emulator: on the wall clock again
    g.close()
    return scanner


def expected_region() -> tuple[float, float, float, float]:
    """The grid points with the whole SPS ring on the 40 x 30 mm specimen, their extent less the 2 mm margin."""
    inside = [(x, y) for x, y in search_points((BOX[0], BOX[1], BOX[3], BOX[4]), STEP)
              if RING <= x <= 40 - RING and RING <= y <= 30 - RING]
    xs, ys = [p[0] for p in inside], [p[1] for p in inside]
    return (min(xs) + 2, min(ys) + 2, max(xs) - 2, max(ys) - 2)


def check_found(scanner: RobotScanner) -> None:
    assert scanner.state == "scanning", scanner.message
    assert scanner.specimen.region == pytest.approx(expected_region())  # (16, 10, 24, 20): inside the specimen
    touch = scanner.specimen.touch
    assert touch is not None and len(touch.touches) + len(touch.misses) == len(touch.points) == 6 * 4
    assert len(touch.touches) == 4
    assert all(abs(z - 8.0) < 0.1 for _, _, z in touch.touches)
    x0, y0, x1, y1 = expected_region()
    assert scanner.plan.waypoints and all(
        x0 - 1e-9 <= w.x_mm <= x1 + 1e-9 and y0 - 1e-9 <= w.y_mm <= y1 + 1e-9 for w in scanner.plan.waypoints)


@pytest.mark.timeout(120)
def test_the_scanner_finds_a_small_specimen_in_a_big_box_on_the_sim_arm() -> None:
    check_found(search({}, timeout_s=90))


@pytest.mark.xdist_group("ur-emulator")  # real-time emulator: one at a time (make test)
@pytest.mark.timeout(180)
def test_the_scanner_finds_a_small_specimen_in_a_big_box_through_ur_rtde(tmp_path: Path) -> None:
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--home", f"0,0,16,0,{math.pi},0", "--phantom", SMALL,
                          "--clock-file", str(writer.path)]) as emu:
            scanner = search({"driver": "ur_rtde", "robot_host": emu.host}, timeout_s=150, clock=writer)
    finally:
        writer.close()
    check_found(scanner)


@pytest.mark.xdist_group("ur-emulator")  # real-time emulator: one at a time (make test)
@pytest.mark.timeout(180)
def test_the_table_touch_beside_the_specimen_through_ur_rtde(tmp_path: Path) -> None:
    """The rig's table touch (table_point_mm) is a real move through ur_rtde: 8 mm left of SMALL's edge the SPS find
    the table (z 0 of the emulator's world) before the specimen's nine touches, and the scanner publishes it."""
    geometry = tmp_path / "small.yaml"
    geometry.write_text("thickness_mm: 8.0\nfootprint_mm: [0, 0, 40, 30]\n")
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--home", f"0,0,16,0,{math.pi},0", "--phantom", SMALL,
                          "--clock-file", str(writer.path)]) as emu:
            scanner = search({"driver": "ur_rtde", "robot_host": emu.host, "search_box_mm": [],
                              "geometry": str(geometry), "region_mm": [8, 8, 32, 22], "table_point_mm": [-8, 15]},
                             timeout_s=150, clock=writer)
    finally:
        writer.close()
    assert scanner.state == "scanning", scanner.message
    assert scanner.specimen.table_z_mm is not None and abs(scanner.specimen.table_z_mm) < 0.1
    touch = scanner.specimen.touch
    assert touch is not None and touch.points[0] == (-8, 15) and len(touch.touches) == 9
    assert all(abs(z - 8.0) < 0.1 for _, _, z in touch.touches)


def test_a_search_box_outside_the_workspace_or_without_a_contact_signal_is_refused_before_motion() -> None:
    import palpa
    from palpa.testing import NodeHarness

    with pytest.raises(palpa.ParamError, match=r"the search box \(search_box_mm\) x -10\.\.90, y -10\.\.40 mm does "
                                               r"not fit the workspace box .* x 90 > x_max 70"):
        NodeHarness(RobotScanner, {"search_box_mm": [-10, -10, 0.5, 90, 40, 16], "touchoff": "heights"})
    with pytest.raises(palpa.ParamError, match=r"search box's heights z 0\.5\.\.80 mm leave the workspace box"):
        NodeHarness(RobotScanner, {"search_box_mm": [-10, -10, 0.5, 50, 40, 80], "touchoff": "heights"})
    with pytest.raises(palpa.ParamError, match="needs a contact signal"):
        NodeHarness(RobotScanner, {"search_box_mm": BOX})


def test_a_probe_sample_counts_for_the_point_it_was_measured_over_not_where_the_arm_is_when_it_is_handled() -> None:
    """On the wall clock a heights sample can be handled after the arm reached the next point though it was measured
    on the way there, over the specimen: it must not make that point a touch (the ur_rtde search once took a point
    whose ring hangs over the specimen's edge for one, its region 12 mm too wide)."""
    from nodes.drivers.robot_sim import SimRobotDriver
    from nodes.scanner.touchoff import TouchOff, TouchOffConfig

    clock = MockClock(0)
    arm = SimRobotDriver(home_mm=(26.0, 8.0, 16.0), clock=clock.now_ns)
    arm.connect()
    touch = TouchOff(arm, [(38.0, 8.0)], TouchOffConfig(signal="heights", start_z_mm=16.0, floor_z_mm=0.5,
                                                        search=True, samples=3))
    touch.start()
    on_the_way: list[int] = []
    for _ in range(2000):   # to the point at the start height, then down until the arm is near the table
        clock.advance(0.002)
        x, y, z = arm.state().pose[:3]
        touch.note_pose(clock.now_ns(), x, y, z)
        if x < 34.0:
            on_the_way.append(clock.now_ns())   # over the specimen (8 mm thick, to x = 40) with the whole ring
        if z < 12.0:
            break
    assert abs(arm.state().pose[0] - 38.0) < 1e-6 and touch.phase == "searching"
    for stamp in on_the_way[-3:]:   # measured over the specimen on the way: 8 mm below the face, all alike
        touch.on_heights(stamp, (8.0, 8.0, 8.0, 8.0))
    assert touch.touches == [] and touch.phase == "searching"
    now = clock.now_ns()
    for k in range(3):   # measured over the point: the ring half over the edge, one SPS at the end of its stroke
        touch.on_heights(now - 2_000_000 * k, (4.0, 4.0, 10.0, 10.0))
    assert touch.touches == [] and touch.misses == [(38.0, 8.0)]
