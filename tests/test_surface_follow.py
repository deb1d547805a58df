"""Issue 15, surface following: the air-float probe's own heights keep its face at the working clearance along a
sweep line where the touched-off surface is wrong (a 2 x 2 touch-off grid fits a plane to a dome: ~1.2 mm low
over the crest). The control law alone, then the scanner with the simulated probe over the dome (in process, mock
clock); tests/test_touchoff_ur.py runs the same through the ur_rtde driver against the UR emulator."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import msgspec
import pytest

from emulators.clock_file import ClockWriter
from messages import ProbeHeights
from models.following import (
    FollowConfig,
    clearance_error,
    densify_slides,
    follow_step,
    gap_from_heights,
    in_working_range,
    is_slide,
)
from models.phantom import load_phantom
from models.raster import sweep_raster
from nodes.probe.fibre_reader import FibreReader
from nodes.probe.pressure_controller import PressureController
from nodes.scanner.robot_scanner import RobotScanner
from nodes.scanner.surface_follow import LineFollower
from palpa.testing import GraphHarness, NodeHarness
from palpa.timing.clock import MockClock

DOME = "phantoms/specimens/dome_6_3.yaml"  # 70 x 40 mm: 6 mm on the centre line y = 20, 3 mm at the y edges
# With a real-time driver (the UR emulator) the harness's clock follows the wall clock, at most MAX_STEP_S per pass
# of the loop: a stall of this process (starved by other workers, or in a ur_rtde call holding the GIL) slows the
# graph's time down instead of jumping it, and the emulator, on the same clock (emulators.clock_file), holds with it
# within its lead. Each line's first SETTLE_S of that time is set apart and counted, not judged: a line starts at
# the plan's height, and the follower's first corrections take the loop's latency (each a ur_rtde path upload) to
# land (in the mock clock's time it settles within the first 4 mm, which all runs leave out).
MAX_STEP_S, SETTLE_S, STALL_S = 0.02, 1.0, 0.25
REGION = [22.0, 6.0, 28.0, 34.0]  # two lines along y, across the crest (x clear of both inclusions' cores)


def test_the_law_closes_the_clearance_error_at_its_gain_capped_and_bounded() -> None:
    cfg = FollowConfig(target_gap_mm=1.0, gain_per_s=5.0, max_rate_mm_s=2.0, max_offset_mm=1.5)
    assert follow_step(0.0, 0.2, 0.01, cfg) == pytest.approx(-0.01)  # 0.2 mm too high: down by gain*dt*error
    assert follow_step(0.0, -0.2, 0.01, cfg) == pytest.approx(+0.01)  # too close: up
    assert follow_step(0.0, 8.0, 0.01, cfg) == pytest.approx(-0.02)  # one wild sample moves it max_rate*dt only
    assert follow_step(-1.49, 2.0, 0.01, cfg) == pytest.approx(-1.5)  # never beyond max_offset
    assert follow_step(0.0, -1.0, 0.1, cfg, limits_mm=(-1.0, 0.05)) == pytest.approx(0.05)  # nor the box's limits
    # a face that follows its own measurement converges on the working clearance over a surface 1 mm off the plan
    u, surface_error = 0.0, 1.0
    for _ in range(300):  # 3 s at 100 Hz
        gap = 1.0 - surface_error + u  # planned 1 mm over a surface that is really 1 mm higher, plus the offset
        e = clearance_error((gap, gap, gap, gap + 1.5), cfg)
        assert e is not None
        u = follow_step(u, e, 0.01, cfg)
    assert u == pytest.approx(1.0, abs=0.01)
    assert gap_from_heights((1.3, 1.3, 1.3, 3.0), cfg) == pytest.approx(1.3)  # eq. 2 on a level surface
    assert clearance_error((1.3, 1.3, 1.3, 3.0), cfg) == pytest.approx(0.3)
    # on a slope d_n says 1.1 mm, but the uphill SPS is 0.1 mm from the face: raise until it is min_sps clear
    assert clearance_error((0.1, 1.6, 1.6, 3.0), cfg) == pytest.approx(0.1 - 0.3)
    assert clearance_error((1.0, 1.0, 10.0, 3.0), cfg) is None  # an SPS sees nothing (over an edge)
    assert in_working_range((0.4, 0.3, 0.5, 2.5)) and not in_working_range((0.0, 0.3, 0.5, 2.5))
    assert not in_working_range((1.0, 1.0, 1.0, 9.8))  # the indenter at the end of its stroke


def test_densified_slides_keep_the_line_and_mark_only_sliding_moves() -> None:
    plan = sweep_raster(0, 0, 10, 20, spacing_mm=10, speed_mm_s=10, contact_z_mm=1.0, surface=lambda x, y: 5.0)
    dense = densify_slides(plan.waypoints, 1.5)
    slides = [w for i, w in enumerate(dense) if is_slide(dense, i)]
    assert len(slides) == 2 * 14  # 20 mm lines in 14 steps of <= 1.5 mm
    assert all(w.z_mm == 6.0 and w.x_mm in (0.0, 10.0) and w.blend_mm == pytest.approx(0.675) for w in slides[:-1]
               if w is not slides[13])
    assert not is_slide(dense, [w.kind for w in dense].index("contact"))  # the descent onto a line is no slide


def geometry(tmp_path: Path) -> str:
    f = tmp_path / "geometry.yaml"
    f.write_text("thickness_mm: 6.0\nfootprint_mm: [0, 0, 70, 40]\n")  # as measured: its top, its footprint
    return str(f)


def sweep_over_the_dome(tmp_path: Path, gain: float, *, clock: ClockWriter | None = None, timeout_s: float = 60.0,
                        **params: Any) -> dict[str, Any]:
    """The scanner (sim arm, or ``params`` for another driver), the sim regulator and the sim fibre probe
    over the dome; touch-off on 2 x 2 points, then two lines at 10 mm/s. ``clock``: the harness's clock follows
    the wall clock (see MAX_STEP_S) and is published there, for a real-time driver that follows it (the UR
    emulator's ``--clock-file``). Returns the probe's samples while sliding (mid-line), the scanner, and with a
    clock the samples set apart (each line's first SETTLE_S), the stalls of this process (s), and a trace."""
    truth = load_phantom(DOME)
    g = GraphHarness(clock=MockClock(time.time_ns()) if clock is not None else None)
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 36.0, "sim_tracking_kpa": 0.0})
    g.add(FibreReader, {"phantom": DOME, "sim_errors": "ideal", "poll_hz": 100.0})
    scanner = g.add(RobotScanner, {
        "geometry": geometry(tmp_path), "region_mm": REGION, "touchoff": "heights", "touch_grid": 2,
        "search_clearance_mm": 6.0, "spacing_mm": 6.0, "speed_mm_s": 10.0, "home_mm": [25, 20, 14],
        "watchdog_s": 0.5, "follow_gain_per_s": gain, "linger_s": 0.1, "retract_clearance_mm": 6.0, **params})
    decoder = msgspec.msgpack.Decoder(ProbeHeights)
    seen = 0
    samples: list[tuple[ProbeHeights, float]] = []  # (sample, true clearance of the face)
    deadline = time.monotonic() + timeout_s
    stalls: list[float] = []
    # per judged sample: graph time (s), y, clearance, follower offset, sent offset (mm), resends
    trace: list[tuple[float, ...]] = []
    t0 = g.clock.now_ns()
    set_apart, last, settled_at, line = 0, time.monotonic(), 0, -1
    for _ in range(int(timeout_s / (0.005 if clock is not None else 0.01))):
        if clock is not None:
            clock.write(g.clock.now_ns())
            time.sleep(0.005)
            now = time.monotonic()
            if now - last > STALL_S:
                stalls.append(round(now - last, 3))
            g.advance(min(now - last, MAX_STEP_S))
            last = now
            if now > deadline:
                break
        else:
            g.advance(0.01)
        raws = g.raw[seen:]
        seen = len(g.raw)
        if scanner.state != "scanning":
            if scanner.state in ("done", "fault"):
                break
            continue
        seg_start = scanner.segments[scanner.segment][0] if scanner.segment < len(scanner.segments) else 0
        i = seg_start + scanner.driver.progress().index
        x, y, z = scanner.driver.state().pose[:3]
        # mid-line: each line starts at the plan's height and the follower settles over its first 4 mm
        if not (is_slide(scanner.path, i) and REGION[1] + 4 < y < REGION[3] - 4):
            continue
        follower = scanner.follower
        if clock is not None and follower is not None and follower.line != line:
            line = follower.line
            settled_at = g.clock.now_ns() + int(SETTLE_S * 1e9)
        for raw in raws:
            if raw.topic != "probe/heights":
                continue
            if clock is not None and g.clock.now_ns() < settled_at:
                set_apart += 1
                continue
            clearance = z - float(truth.surface_z(x, y))
            samples.append((decoder.decode(raw.payload), clearance))
            trace.append(((g.clock.now_ns() - t0) / 1e9, y, clearance, follower.offset_mm if follower else 0.0,
                          follower.sent_mm if follower else 0.0, follower.resends if follower else 0))
    if clock is not None:
        clock.release()  # the driver's teardown waits for the emulator, which no longer needs to wait for us
    g.close()
    return {"scanner": scanner, "samples": samples, "set_apart": set_apart, "stalls": stalls, "trace": trace}


def check_without_and_with_following(free: dict[str, Any], followed: dict[str, Any]) -> None:
    """Without following the face rests on the crest; with it, :func:`check_following`."""
    s = free["scanner"]
    assert s.state == "done", s.message
    out = [m for m, _ in free["samples"] if not in_working_range(m.h_mm)]
    assert len(free["samples"]) > 500 and len(out) > 0.15 * len(free["samples"])  # the face rests on the crest
    check_following(followed)


def check_following(followed: dict[str, Any]) -> None:
    """The premise (the 2 x 2 fit ~1 mm under the crest: a face on the plan rests on it), and with following every
    mid-line sample in the working range, the face 0.4-1.5 mm above the tissue."""
    truth = load_phantom(DOME)
    s = followed["scanner"]
    assert s.state == "done", s.message
    fit = s.specimen.surface
    assert fit.model == "plane" and fit.z(25, 20) < float(truth.surface_z(25, 20)) - 0.9  # the premise: 1 mm off
    assert s.follower is not None and s.follower.resends > 5
    got = followed["samples"]
    assert len(got) > 500, (len(got), "samples set apart (line starts):", followed.get("set_apart"),
                            "stalls of this process (s):", followed.get("stalls"))
    worst = min(range(len(got)), key=lambda i: min(got[i][0].h_mm[:3]))
    trace = followed.get("trace")
    if not all(in_working_range(m.h_mm) for m, _ in got) and trace:
        print("before the worst sample: graph time (s), y, clearance, follower offset, sent offset (mm), resends")
        for row in trace[max(0, worst - 60): worst + 1: 4]:
            print(" ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row))
    assert all(in_working_range(m.h_mm) for m, _ in got), (min(got[worst][0].h_mm[:3]), "stalls of this process "
                                                           "(s):", followed.get("stalls"))
    clearances = [c for _, c in got]
    assert min(clearances) > 0.4 and max(clearances) < 1.5, (min(clearances), max(clearances), "stalls (s):",
                                                             followed.get("stalls"))
    assert all(0.3 < m.d_in_mm < 5.0 for m, _ in got)  # eqs. 1-3's indentation inside the estimator's range


@pytest.mark.timeout(240)
def test_following_keeps_the_face_at_its_clearance_where_the_coarse_touch_off_is_a_millimetre_off(
        tmp_path: Path) -> None:
    check_without_and_with_following(sweep_over_the_dome(tmp_path, gain=0.0), sweep_over_the_dome(tmp_path, gain=10.0))


def test_the_follower_never_takes_a_line_out_of_the_box_nor_follows_off_the_line() -> None:
    plan = densify_slides(sweep_raster(0, 0, 10, 20, spacing_mm=10, speed_mm_s=10, contact_z_mm=1.0,
                                       surface=lambda x, y: 0.0).waypoints, 1.5)
    f = LineFollower(FollowConfig(target_gap_mm=1.0), (0.5, 60.0))
    f.start_line(plan, 0)
    assert f.limits == (0.5 - 1.0, 60.0 - 1.0)  # the line's contact heights are at z 1 mm
    for k in range(201):
        f.note_pose(k * 10_000_000, 0.0, 5.0, 1.0)
    f.track(plan, 0)  # heading for the transit: not sliding, samples ignored
    f.on_heights(0, (3.0, 3.0, 3.0, 5.0), True)
    f.on_heights(10_000_000, (3.0, 3.0, 3.0, 5.0), True)
    assert f.offset_mm == 0.0 and not f.due(10**9)
    f.track(plan, [w.kind for w in plan].index("contact") + 1)  # sliding
    for k in range(200):  # the face reads 2 mm too high for 2 s: down, but only to the box's floor
        f.on_heights(k * 10_000_000, (3.0, 3.0, 3.0, 5.0), True)
    assert f.offset_mm == pytest.approx(-0.5) and f.due(2 * 10**9)
    assert min(w.z_mm for w in f.shifted(plan)) == pytest.approx(0.5)
    f.start_line(plan, 1)  # the next line starts beside where this one ended: at its offset
    assert f.offset_mm == pytest.approx(-0.5) and not f.sliding and not f.due(3 * 10**9)
    f.start_line(plan, 0)  # any other line (a new scan) starts on its plan
    assert f.offset_mm == 0.0


def test_stale_probe_data_still_stops_the_arm_while_following(tmp_path: Path) -> None:
    """The sim arm sweeping with following on, its probe's heights stop mid-line: the watchdog stops it."""
    h = NodeHarness(RobotScanner, {
        "geometry": geometry(tmp_path), "region_mm": REGION, "touchoff": "heights", "touch_grid": 2,
        "spacing_mm": 6.0, "speed_mm_s": 10.0, "home_mm": [25, 20, 14], "watchdog_s": 0.1})
    for _ in range(int(60 / 0.004)):
        x, y, z = h.node.driver.state().pose[:3]
        gap = min(max(z - 5.0, 0.0), 10.0)  # a level surface at 5 mm
        h.publish("probe/heights", ProbeHeights(stamp_ns=h.clock.now_ns(), seq=0, h_mm=(gap, gap, gap, gap + 1.5),
                                                raw=(0, 0, 0, 0), d_in_mm=1.5, tilt_rad=0.0))
        h.advance(0.004)
        if h.node.follower is not None and h.node.follower.sliding and y > 15:
            break
    assert h.node.state == "scanning" and h.node.follower is not None and h.node.follower.sliding
    h.advance(0.3)  # no more heights
    state: str = h.node.state  # (mypy narrowed it to "scanning" above)
    assert state == "fault" and "stale" in h.node.message
    h.advance(0.2)
    assert h.node.driver.progress().status.value == "stopped"


def follow_with_late_samples(plan_z: bool) -> list[float]:
    """A face over a level surface at 0 whose plan (fit + 1 mm) is 0.6 mm low, samples delivered 0.2 s late and the
    arm taking a re-sent offset at once: the offsets asked, every 2 ms for 3 s."""
    plan = densify_slides(sweep_raster(0, 0, 10, 200, spacing_mm=10, speed_mm_s=10, contact_z_mm=1.0,
                                       surface=lambda x, y: -0.6).waypoints, 1.5)
    f = LineFollower(FollowConfig(target_gap_mm=1.0, gain_per_s=10.0), (0.0, 60.0))
    f.start_line(plan, 0, (lambda x, y: 0.4) if plan_z else None)
    f.track(plan, [w.kind for w in plan].index("contact") + 1)
    faces: list[float] = []  # the face's height every 2 ms
    asked = []
    for k in range(1500):
        now = k * 2_000_000
        faces.append(0.4 + f.sent_mm)
        f.note_pose(now, 0.0, 10.0, faces[-1])
        if k >= 100:  # the sample taken 0.2 s ago arrives now
            gap = faces[k - 100]
            f.on_heights(now - 200_000_000, (gap, gap, gap, gap + 1.5), True)
        if f.due(now):
            f.sent(now)
        asked.append(f.sent_mm)
    return asked


def test_late_samples_are_read_against_where_the_face_was_so_the_delay_cannot_make_it_oscillate() -> None:
    naive = follow_with_late_samples(plan_z=False)
    assert max(naive) > 0.6 + 0.2  # the premise: the error alone, 0.2 s late, overshoots (and rings)
    asked = follow_with_late_samples(plan_z=True)
    assert max(asked) < 0.6 + 0.1 and asked[-1] == pytest.approx(0.6, abs=0.1)
