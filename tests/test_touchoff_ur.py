"""Issue 15 through the ur_rtde driver against the UR emulator: the touch-off finds a domed specimen's surface by
the TCP force (actual_TCP_force from the emulator's contact model over the world), and a sweep planned over the
fitted surface keeps the probe's indentation in its working range along the dome."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from emulators.clock_file import ClockWriter
from models.phantom import load_phantom
from models.raster import sweep_raster
from models.surface import fit_surface, touch_points
from nodes.drivers.robot import MotionStatus
from nodes.drivers.robot_urrtde import URRtdeDriver
from nodes.scanner.touchoff import TouchOff, TouchOffConfig
from tests.procs import EMULATOR_START_S, ur_emulator
from tests.test_surface_follow import check_following, sweep_over_the_dome

# the UR emulator moves in real time: its tests run one at a time on one xdist worker (make test, --dist loadgroup)
pytestmark = [pytest.mark.system, pytest.mark.xdist_group("ur-emulator")]

DOME = "phantoms/specimens/dome_6_3.yaml"  # 70 x 40 mm, 6 mm on the centre line, 3 mm at the y edges


@pytest.mark.timeout(90)
def test_touchoff_by_force_and_a_sweep_over_the_found_dome_on_the_ur_emulator() -> None:
    truth = load_phantom(DOME)
    # a wrist F/T sensor's noise (ATI Nano17 class: a few mN), its offset up to 3 N until the touch-off's zero
    with ur_emulator(["--unlock-delay", "0", "--home", f"20,10,7,0,{math.pi},0", "--phantom", DOME,
                      "--force-noise", "0.003"]) as emu:
        ur = URRtdeDriver(emu.host, watchdog_hz=5.0, start_timeout_s=EMULATOR_START_S)
        try:
            ur.connect()
            # 20 x 20 mm over the crest (6 mm on y = 20, ~5.3 at the region's edges), each descent from 1 mm over it
            region = (20.0, 10.0, 40.0, 30.0)
            touch = TouchOff(ur, touch_points(region, 3), TouchOffConfig(
                signal="force", start_z_mm=7.0, floor_z_mm=0.5, search_speed_mm_s=5.0, transit_speed_mm_s=60.0,
                accel_mm_s2=1000.0, threshold=0.3))
            touch.start()
            deadline = time.monotonic() + 60
            while not (touch.done or touch.failed) and time.monotonic() < deadline:
                touch.step()
                time.sleep(0.002)
            assert touch.done, touch.error or "touch-off timed out"
            errors = [z - float(truth.surface_z(x, y)) for x, y, z in touch.touches]
            # within 0.12 mm however often step() ran (a busy PC reads the rise fewer times: then it descends again
            # more slowly); with this sensor's noise the sim arm's 108 touches in tests/test_touchoff_force.py are
            # within 0.094 mm, rms 0.034
            assert len(errors) == 9 and max(abs(e) for e in errors) < 0.12, (errors, touch.reapproaches)
            fit = fit_surface(touch.touches)
            # sweep two lines across the dome pressing 0.5 mm below the found surface: the force must stay on
            plan = sweep_raster(20, 10, 40, 30, spacing_mm=20, speed_mm_s=10, contact_z_mm=-0.5, surface=fit,
                                approach_clearance_mm=1.5, retract_clearance_mm=3, transit_speed_mm_s=60,
                                approach_speed_mm_s=10, accel_mm_s2=1000)
            ur.move_path(plan.waypoints)
            depths, forces = [], []
            deadline = time.monotonic() + 30
            while ur.progress().status == MotionStatus.MOVING and time.monotonic() < deadline:
                st = ur.state()
                x, y, z = st.pose[:3]
                vx, vy = st.speed_mm_s[:2]
                if 9 < abs(vy) < 11 and abs(vx) < 1:  # sliding along a line (y) at the sweep speed
                    depths.append(float(truth.surface_z(x, y)) - z)
                    forces.append(st.force_n[2] - touch.force_zero_n)  # the sensor's offset, as the touch-off read it
                time.sleep(0.005)
            assert ur.progress().status == MotionStatus.DONE
            assert len(depths) > 50
            assert min(depths) > 0.35 and max(depths) < 0.65, (min(depths), max(depths))
            assert min(forces) > 0.01  # in contact all along (0.5 mm in: ~0.04 N; the sensor's noise 0.003 N)
        finally:
            ur.close()


@pytest.mark.timeout(60)
def test_the_robot_s_own_force_sensor_is_too_coarse_to_touch_off_the_dome_and_the_touch_off_says_so() -> None:
    """The emulator's default sensor (sigma 1 N, a UR's built-in one at its best) against a 0.5 N threshold: the
    touch-off reads the spread at rest over the first point and refuses before descending, naming it."""
    with ur_emulator(["--unlock-delay", "0", "--home", f"20,10,7,0,{math.pi},0", "--phantom", DOME]) as emu:
        ur = URRtdeDriver(emu.host, watchdog_hz=5.0, start_timeout_s=EMULATOR_START_S)
        try:
            ur.connect()
            touch = TouchOff(ur, [(30.0, 20.0)], TouchOffConfig(signal="force", start_z_mm=7.0, floor_z_mm=0.5,
                                                                threshold=0.5))
            touch.start()
            deadline = time.monotonic() + 30
            while not (touch.done or touch.failed) and time.monotonic() < deadline:
                touch.step()
                time.sleep(0.002)
            assert touch.failed and "would be crossed by noise" in touch.error, touch.error
            assert 0.5 < touch.force_noise_n < 1.5  # sigma from 20 readings: within ~3 of its standard errors
            assert ur.state().pose[2] == pytest.approx(7.0, abs=0.01)  # it never went down
        finally:
            ur.close()


@pytest.mark.timeout(150)
def test_the_scanner_follows_the_dome_by_the_probe_heights_through_ur_rtde(tmp_path: Path) -> None:
    """The scanner node on the ur_rtde driver against the emulator, with the simulated air-float probe over the same
    dome (in process, the harness's clock on the wall clock): a 2 x 2 touch-off by the probe's heights fits a plane
    ~1.2 mm under the crest, and following keeps every mid-line sample's SPS ring clear of the tissue and the face
    0.4-1.5 mm above it, each correction a new ur_rtde path (the face resting on the crest without following:
    tests/test_surface_follow.py, on the sim arm).

    The emulator follows the harness's clock (``--clock-file``, emulators.clock_file): following cannot correct while
    the process that runs it is stopped (starved by the other workers, or in a ur_rtde call holding the GIL), and on
    a loaded machine this process has stalled for up to 1.7 s, 17 mm of the line at 10 mm/s. On the rig that is a
    PC unfit to follow, and the RTDE watchdog's business (tested in tests/test_robot_drivers.py and
    tests/test_ur_emulator.py); here the arm holds with the graph's time, within the emulator's 0.1 s lead, and
    every mid-line sample is judged but those of each line's first second."""
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--home", f"25,20,14,0,{math.pi},0", "--phantom", DOME,
                          "--clock-file", str(writer.path)]) as emu:
            run = sweep_over_the_dome(tmp_path, gain=10.0, clock=writer, timeout_s=90.0, driver="ur_rtde",
                                      robot_host=emu.host, rtde_watchdog_hz=0.0)
            assert not any("watchdog" in m for m in emu.command("messages")["messages"])   # the scanner set none
    finally:
        writer.close()
    print(f"{run['set_apart']} samples set apart (each line's first second); {len(run['samples'])} judged; this "
          f"process stalled {len(run['stalls'])} times: {run['stalls']}")
    check_following(run)
