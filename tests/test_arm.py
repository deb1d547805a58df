"""models.arm: trapezoidal moveL, blended paths, stopL, speedL, caps and determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from models.arm import TICK_S, ArmModel, ArmStatus, ArmTarget

DOWN = (0.0, math.pi, 0.0)


def pose(x: float, y: float, z: float, rot: tuple[float, float, float] = DOWN) -> tuple[float, ...]:
    return (x, y, z, *rot)


def run(arm: ArmModel, limit_s: float = 120.0) -> list[tuple[float, tuple[float, ...], tuple[float, ...], int]]:
    """Step tick by tick until the arm rests; (time, pose, twist, index) per tick."""
    out = []
    for _ in range(int(limit_s / TICK_S)):
        arm.step(TICK_S)
        out.append((arm.time_s, arm.pose, arm.tcp_speed, arm.path_index))
        if not arm.is_moving:
            return out
    raise AssertionError(f"arm still moving after {limit_s} s")


def speeds(trace: list) -> np.ndarray:
    return np.array([np.linalg.norm(t[2][:3]) for t in trace])


def test_move_l_trapezoid_reaches_target_on_time() -> None:
    arm = ArmModel(pose(0, 0, 100))
    arm.move_l(pose(100, 0, 100), 50.0, 200.0)
    trace = run(arm)
    # 100 mm at 50 mm/s with 0.25 s ramps: 100/50 + 50/200 = 2.25 s
    assert trace[-1][0] == pytest.approx(2.25, abs=TICK_S)
    assert arm.pose == pose(100, 0, 100)
    assert arm.done and arm.status is ArmStatus.DONE and arm.path_index == 0
    assert speeds(trace).max() == pytest.approx(50.0)
    assert arm.tcp_speed == (0.0,) * 6


def test_short_move_is_triangular() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_l(pose(4, 0, 0), 100.0, 100.0)
    trace = run(arm)
    # peak of a triangle: sqrt(a * d) = 20 mm/s, reached after 0.2 s; total 0.4 s
    assert speeds(trace).max() == pytest.approx(20.0, abs=100.0 * TICK_S)
    assert trace[-1][0] == pytest.approx(0.4, abs=TICK_S)


def test_commanded_speed_and_accel_are_clamped_to_the_caps() -> None:
    arm = ArmModel(pose(0, 0, 0), max_speed_mm_s=30.0, max_accel_mm_s2=60.0)
    arm.move_l(pose(200, 0, 0), 500.0, 5000.0)
    trace = run(arm)
    v = speeds(trace)
    assert v.max() == pytest.approx(30.0)
    assert np.abs(np.diff(v)).max() / TICK_S <= 60.0 + 1e-6


def test_blend_cuts_the_corner_without_stopping() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_path([ArmTarget(pose(20, 0, 0), 10.0, 500.0, blend_mm=2.0), ArmTarget(pose(20, 20, 0), 10.0, 500.0)])
    trace = run(arm)
    pts = np.array([t[1][:3] for t in trace])
    corner = np.linalg.norm(pts - np.array([20, 0, 0]), axis=1)
    near = corner < 2.0
    assert near.any()
    assert 0.2 < corner.min() < 2.0  # passes inside the blend radius, not through the corner
    assert speeds(trace)[near].min() > 1.0  # keeps moving through the blend
    assert arm.pose == pose(20, 20, 0)


def test_without_blend_the_arm_stops_at_the_corner() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_path([ArmTarget(pose(20, 0, 0), 10.0, 500.0), ArmTarget(pose(20, 20, 0), 10.0, 500.0)])
    trace = run(arm)
    at_corner = [t for t in trace if np.allclose(t[1][:3], (20, 0, 0), atol=1e-9)]
    assert at_corner and all(np.linalg.norm(t[2][:3]) < 1e-6 for t in at_corner)


def test_path_index_counts_waypoints_and_advances_at_blends() -> None:
    arm = ArmModel(pose(0, 0, 0))
    targets = [ArmTarget(pose(10 * (i + 1), 5 * (i % 2), 0), 40.0, 400.0, 1.0) for i in range(6)]
    arm.move_path(targets)
    indices = [t[3] for t in run(arm)]
    assert indices == sorted(indices)
    assert sorted(set(indices)) == list(range(6))
    assert arm.path_index == 5 and arm.done


def test_stop_l_decelerates_along_the_path() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_l(pose(100, 0, 0), 50.0, 200.0)
    arm.step(1.0)  # cruising at 50 mm/s
    x0 = arm.pose[0]
    arm.stop_l(500.0)
    assert arm.status is ArmStatus.STOPPING
    trace = run(arm)
    assert arm.status is ArmStatus.STOPPED and not arm.done
    assert arm.pose[0] - x0 == pytest.approx(50.0**2 / (2 * 500.0), abs=1e-6)
    assert trace[-1][0] - 1.0 == pytest.approx(0.1, abs=TICK_S)


def test_stop_l_never_overruns_the_path_end() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_l(pose(10, 0, 0), 50.0, 1000.0)
    arm.step(0.19)  # decelerating close to the end
    arm.stop_l(1.0)  # far too gentle to stop before x = 10
    run(arm)
    assert arm.pose[0] <= 10.0 + 1e-9


def test_new_path_while_moving_decelerates_first() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_l(pose(100, 0, 0), 50.0, 200.0)
    arm.step(1.0)
    arm.move_l(pose(0, 30, 0), 20.0, 200.0)
    trace = run(arm)
    v = speeds(trace)
    assert np.abs(np.diff(v)).max() / TICK_S <= 200.0 + 1e-6  # no speed jump
    assert arm.pose == pose(0, 30, 0) and arm.done


def test_speed_l_ramps_holds_and_stops() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.speed_l((10.0, 0, 0, 0, 0, 0), 100.0)
    arm.step(1.0)
    assert arm.tcp_speed[0] == pytest.approx(10.0)
    assert arm.pose[0] == pytest.approx(0.5 + 9.0, abs=1e-9)  # 0.1 s ramp then 0.9 s at 10 mm/s
    arm.stop_l(100.0)
    run(arm)
    assert arm.status is ArmStatus.STOPPED and arm.pose[0] == pytest.approx(10.0, abs=1e-9)


def test_speed_l_with_duration_ends_done() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.speed_l((0, 10.0, 0, 0, 0, 0), 100.0, duration_s=1.0)
    run(arm)
    assert arm.done and arm.pose[1] == pytest.approx(10.0, abs=1e-9)


def test_orientation_interpolates_and_pure_rotation_uses_rad_per_s() -> None:
    arm = ArmModel(pose(0, 0, 0, (0.0, 0.0, 0.0)))
    arm.move_l(pose(0, 0, 0, (0.0, 0.0, 0.5)), 100.0, 1000.0)  # 0.5 rad at 0.1 rad/s, 1 rad/s^2
    trace = run(arm)
    assert trace[-1][0] == pytest.approx(5.0 + 0.1, abs=TICK_S)
    assert max(t[2][5] for t in trace) == pytest.approx(0.1)
    assert arm.pose == (0.0, 0.0, 0.0, 0.0, 0.0, 0.5)
    arm.move_l(pose(10, 0, 0, (0.2, 0.0, 0.5)), 10.0, 100.0)
    arm.step(0.55)  # half way along x
    half = Rotation.from_rotvec(arm.pose[3:])
    expected = Rotation.from_rotvec((0.1, 0.0, 0.5))
    assert arm.pose[0] == pytest.approx(5.0, abs=0.05)
    assert (half * expected.inv()).magnitude() < 0.01


def test_fixed_orientation_keeps_the_given_rotation_vector() -> None:
    arm = ArmModel(pose(0, 0, 0, (0.0, -math.pi, 0.0)))
    arm.move_l(pose(5, 5, 0, (0.0, -math.pi, 0.0)), 10.0, 100.0)
    arm.step(0.3)
    assert arm.pose[3:] == (0.0, -math.pi, 0.0)


@pytest.mark.parametrize("bad", [
    ArmTarget(pose(1, 0, 0), 0.0, 100.0), ArmTarget(pose(1, 0, 0), 10.0, -1.0),
    ArmTarget(pose(1, 0, 0), 10.0, 100.0, -0.5), ArmTarget((1.0, 0.0, math.nan, 0.0, 0.0, 0.0), 10.0, 100.0),
])
def test_invalid_waypoints_are_refused_by_index(bad: ArmTarget) -> None:
    arm = ArmModel(pose(0, 0, 0))
    with pytest.raises(ValueError, match="waypoint 1"):
        arm.move_path([ArmTarget(pose(1, 1, 0), 10.0, 100.0), bad])
    assert not arm.is_moving


def test_set_pose_only_at_rest() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_l(pose(10, 0, 0), 10.0, 100.0)
    with pytest.raises(RuntimeError, match="moving"):
        arm.set_pose(pose(5, 5, 5))


waypoint = st.builds(
    lambda x, y, z, v, a, r: ArmTarget(pose(x, y, z), v, a, r),
    st.floats(-15, 15), st.floats(-15, 15), st.floats(0, 15),
    st.floats(10, 200), st.floats(50, 3000), st.floats(0, 5),
)


@settings(max_examples=20, deadline=None)
@given(st.lists(waypoint, min_size=1, max_size=6))
def test_never_faster_or_harder_than_commanded(path: list[ArmTarget]) -> None:
    arm = ArmModel(pose(0, 0, 10))
    arm.move_path(path)
    trace = run(arm)
    v = speeds(trace)
    assert v.max(initial=0.0) <= max(t.speed_mm_s for t in path) + 1e-6
    assert np.abs(np.diff(v, prepend=0.0)).max(initial=0.0) <= max(t.accel_mm_s2 for t in path) * TICK_S + 1e-6
    assert np.allclose(arm.pose[:3], path[-1].pose[:3])


@settings(max_examples=10, deadline=None)
@given(st.lists(waypoint, min_size=1, max_size=4), st.lists(st.integers(1, 400), min_size=1, max_size=30),
       st.floats(0.05, 2.0))
def test_same_total_time_same_state_whatever_the_step_sizes(path: list[ArmTarget], chunks: list[int],
                                                             stop_after_s: float) -> None:
    def simulate(step_sizes_ms: list[int]) -> tuple:
        arm = ArmModel(pose(0, 0, 10))
        arm.move_path(path)
        arm.step_ns(round(stop_after_s * 1e9))
        arm.stop_l(500.0)
        for k in step_sizes_ms:
            arm.step_ns(k * 333_333)  # not a multiple of the 2 ms tick: remainders carry over
        return arm.pose, arm.tcp_speed, arm.path_index, arm.status, arm.ticks

    total = sum(chunks)
    assert simulate(chunks) == simulate([total])


def test_blend_at_a_reversal_becomes_a_stop() -> None:
    arm = ArmModel(pose(0, 0, 0))
    arm.move_path([ArmTarget(pose(10, 0, 0), 50.0, 500.0, blend_mm=2.0), ArmTarget(pose(0, 0.01, 0), 50.0, 500.0)])
    trace = run(arm, limit_s=5.0)
    assert min(abs(t[1][0] - 10.0) for t in trace) < 1e-9  # went all the way to the waypoint
    assert arm.done and arm.pose == pose(0, 0.01, 0)


def test_a_path_pieces_pose_and_twist_are_its_position_rotation_and_twist_to_the_bit() -> None:
    """The arm model reads each tick's pose and twist with Primitive.pose_at / twist6_per_mm (issue 40: no numpy
    call per 3-vector); they are position(), rotvec() and twist_per_mm() to the last bit, on lines, blends, pure
    rotations."""
    from models.arm_path import PathPlan

    turn = (0.2, math.pi - 0.3, 0.1)
    plan = PathPlan(pose(0, 0, 100), [ArmTarget(pose(40, 0, 100), 50.0, 500.0, 8.0),
                                      ArmTarget(pose(40, 30, 90, turn), 50.0, 500.0, 5.0),
                                      ArmTarget(pose(40, 30, 90, DOWN), 50.0, 500.0),
                                      ArmTarget(pose(40, 30, 90, DOWN), 50.0, 500.0)])
    kinds = {(p.ctrl is not None, bool(np.any(p.dw)), p.lin > 1e-9) for p in plan.prims}
    assert {(True, True, True), (False, True, False), (False, False, True)} <= kinds
    for prim in plan.prims:
        for u in np.linspace(0.0, prim.length, 41).tolist() + [prim.length * 0.3337]:
            want = tuple(np.concatenate((prim.position(u), prim.rotvec(u))).tolist())
            got = prim.pose_at(u)
            assert np.array(got).tobytes() == np.array(want).tobytes() and all(type(v) is float for v in got)
            lin, ang = prim.twist_per_mm(u)
            assert (prim.twist6_per_mm(u) * 7.5).tobytes() == np.concatenate((lin * 7.5, ang * 7.5)).tobytes()
