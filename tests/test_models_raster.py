"""Raster paths (issue 8): boustrophedon sweep and indentation grids, durations, workspace."""

from __future__ import annotations

import math

import pytest

from models.raster import (
    Waypoint,
    WorkspaceBox,
    WorkspaceViolation,
    check_workspace,
    estimate_duration_s,
    indent_raster,
    line_positions,
    move_time_s,
    sweep_raster,
)


def sweep(**kw: object) -> object:
    args: dict[str, object] = {"spacing_mm": 5.0, "speed_mm_s": 10.0, "contact_z_mm": 20.0}
    args.update(kw)
    return sweep_raster(0, 0, 60, 40, **args)  # type: ignore[arg-type]


def test_sweep_is_boustrophedon_along_y() -> None:
    plan = sweep_raster(0, 0, 60, 40, spacing_mm=5, speed_mm_s=10, contact_z_mm=20, offset_mm=1)
    assert plan.mode == "sweep" and plan.line_count == 13 and plan.line_spacing_mm == 5.0
    assert len(plan.waypoints) == 13 * 5
    for i in range(13):
        wps = [w for w in plan.waypoints if w.line == i]
        assert [w.kind for w in wps] == ["transit", "approach", "contact", "contact", "retract"]
        assert {w.x_mm for w in wps} == {5.0 * i}  # lines parallel to y, stepped along x
        start, end = (0, 40) if i % 2 == 0 else (40, 0)
        assert (wps[2].y_mm, wps[3].y_mm) == (start, end)
        assert wps[2].z_mm == wps[3].z_mm == 21.0  # contact height + offset
        assert wps[3].speed_mm_s == 10.0  # the slide runs at the scan speed
        assert wps[1].z_mm == 25.0 and wps[0].z_mm == wps[4].z_mm == 40.0
    # Consecutive lines start where the previous one ended: transits are one spacing long.
    for prev, nxt in zip(plan.waypoints[4::5], plan.waypoints[5::5], strict=False):
        assert math.dist((prev.x_mm, prev.y_mm), (nxt.x_mm, nxt.y_mm)) == pytest.approx(5.0)
        assert prev.z_mm == nxt.z_mm


def test_sweep_along_x_and_uneven_spacing_covers_both_edges() -> None:
    plan = sweep_raster(10, 5, 30, 65, spacing_mm=7, speed_mm_s=10, contact_z_mm=0, axis="x")
    ys = sorted({w.y_mm for w in plan.waypoints if w.kind == "contact"})
    assert plan.line_count == 10 and ys[0] == 5 and ys[-1] == 65
    assert plan.line_spacing_mm == pytest.approx(60 / 9) and plan.line_spacing_mm <= 7
    line0 = [w for w in plan.waypoints if w.line == 0 and w.kind == "contact"]
    assert [(w.x_mm, w.y_mm) for w in line0] == [(10, 5), (30, 5)]


def test_line_positions() -> None:
    assert line_positions(0, 10, 5) == [0, 5, 10]
    assert line_positions(0, 10, 4) == pytest.approx([0, 10 / 3, 20 / 3, 10])
    assert line_positions(3, 3, 1) == [3]
    assert line_positions(0, 1, 5) == [0, 1]
    with pytest.raises(ValueError, match="spacing_mm"):
        line_positions(0, 10, 0)
    with pytest.raises(ValueError, match="lo <= hi"):
        line_positions(10, 0, 1)


def test_indent_grid_sequence_and_depth() -> None:
    plan = indent_raster(
        0, 0, 20, 10, spacing_mm=10, point_spacing_mm=5, contact_z_mm=20, depth_mm=3, hold_s=0.5
    )
    wps = plan.waypoints
    assert plan.mode == "indent" and plan.line_count == 3
    assert wps[0].kind == "transit" and wps[-1].kind == "retract"
    body = wps[1:-1]
    assert len(body) == 3 * 3 * 4  # 3 lines x 3 points x (approach, press, hold, lift)
    for j in range(0, len(body), 4):
        a, p, h, lift = body[j : j + 4]
        assert [w.kind for w in (a, p, h, lift)] == ["approach", "press", "hold", "lift"]
        assert len({(w.x_mm, w.y_mm) for w in (a, p, h, lift)}) == 1
        assert p.z_mm == h.z_mm == 17.0 and a.z_mm == lift.z_mm == 25.0
        assert h.hold_s == 0.5 and a.hold_s == p.hold_s == lift.hold_s == 0.0
    presses = [(w.x_mm, w.y_mm) for w in wps if w.kind == "press"]
    assert presses[:3] == [(0, 0), (0, 5), (0, 10)]
    assert presses[3:6] == [(10, 10), (10, 5), (10, 0)]  # boustrophedon
    assert wps[-1].z_mm == 40.0


def test_move_time_trapezoid_and_triangle() -> None:
    assert move_time_s(100, 50, 500) == pytest.approx(2.1)  # cruise 2 s + ramps 0.1 s
    assert move_time_s(1, 50, 500) == pytest.approx(2 * math.sqrt(1 / 500))
    assert move_time_s(5, 50, 500) == pytest.approx(0.2)  # both formulas meet at v^2/a
    assert move_time_s(0, 50, 500) == 0.0


def test_duration_of_a_one_line_sweep_by_hand() -> None:
    plan = sweep_raster(
        0, 0, 0, 100, spacing_mm=1, speed_mm_s=10, contact_z_mm=0, approach_clearance_mm=5,
        retract_clearance_mm=20, approach_speed_mm_s=5, transit_speed_mm_s=50, accel_mm_s2=500,
    )  # fmt: skip
    assert plan.line_count == 1
    expected = (
        move_time_s(15, 50, 500)  # down to approach height
        + move_time_s(5, 5, 500)  # slow descent to contact
        + move_time_s(100, 10, 500)  # the slide
        + move_time_s(20, 50, 500)  # retract
    )
    assert plan.duration_s == pytest.approx(expected)
    assert estimate_duration_s(plan.waypoints) == plan.duration_s
    held = indent_raster(0, 0, 0, 0, spacing_mm=1, contact_z_mm=0, depth_mm=2, hold_s=1.5)
    assert held.duration_s == pytest.approx(
        move_time_s(15, 50, 500) + 2 * move_time_s(7, 2, 500) + 1.5 + move_time_s(15, 50, 500)
    )


def test_blends_only_off_tissue_and_clipped() -> None:
    plan = sweep_raster(0, 0, 10, 40, spacing_mm=2, speed_mm_s=10, contact_z_mm=0, blend_mm=3)
    wps = plan.waypoints
    assert wps[0].blend_mm == 0 and wps[-1].blend_mm == 0
    for w in wps:
        if w.kind in ("contact", "press", "hold"):
            assert w.blend_mm == 0
    transits = [w for w in wps[1:] if w.kind == "transit"]
    assert transits and all(w.blend_mm == pytest.approx(1.0) for w in transits)  # half of 2 mm
    approaches = [w for w in wps if w.kind == "approach"]
    assert all(w.blend_mm == pytest.approx(2.5) for w in approaches)  # half of the 5 mm descent


def test_workspace_check_names_the_offending_waypoint() -> None:
    plan = indent_raster(0, 0, 10, 10, spacing_mm=5, contact_z_mm=2, depth_mm=3, hold_s=0.0)
    inside = WorkspaceBox(-1, 11, -1, 11, -1, 30)
    check_workspace(plan.waypoints, inside)
    table = WorkspaceBox(-1, 11, -1, 11, 0, 30)  # the press goes 1 mm into the table
    with pytest.raises(WorkspaceViolation) as err:
        check_workspace(plan.waypoints, table)
    e = err.value
    assert e.index == 2 and e.waypoint is plan.waypoints[2] and e.bound == "z_min"
    assert e.waypoint.kind == "press"
    assert "waypoint 2 (press, line 0" in str(e) and "z_min=0" in str(e)
    narrow = WorkspaceBox(-1, 11, -1, 8, -1, 30)
    with pytest.raises(WorkspaceViolation, match="above the workspace's y_max=8") as err2:
        check_workspace(plan.waypoints, narrow)
    assert plan.waypoints[err2.value.index].y_mm == 10
    assert all(w.y_mm <= 8 for w in plan.waypoints[: err2.value.index])
    nan = Waypoint(0, math.nan, 1, 1, 1, 0, 0, 0, "transit")
    with pytest.raises(WorkspaceViolation) as err3:
        check_workspace([nan], inside)
    assert err3.value.bound == "finite"
    with pytest.raises(ValueError, match="z_min <= z_max"):
        WorkspaceBox(0, 1, 0, 1, 2, 1)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"spacing_mm": 0}, "spacing_mm"),
        ({"speed_mm_s": -1}, "speed_mm_s"),
        ({"accel_mm_s2": math.inf}, "accel_mm_s2"),
        ({"blend_mm": -1}, "blend_mm"),
        ({"axis": "z"}, "axis"),
        ({"offset_mm": 6}, "scan height <= approach height"),
        ({"approach_clearance_mm": 30}, "approach height <= retract height"),
    ],
)
def test_sweep_rejects_bad_parameters(kw: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        sweep(**kw)


def test_indent_rejects_bad_parameters() -> None:
    base = {"spacing_mm": 5.0, "contact_z_mm": 10.0, "depth_mm": 2.0, "hold_s": 0.0}
    for kw, match in (({"depth_mm": 0}, "depth_mm"), ({"hold_s": -1}, "hold_s"),
                      ({"point_spacing_mm": 0}, "spacing_mm")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            indent_raster(0, 0, 10, 10, **{**base, **kw})  # type: ignore[arg-type]
