"""Robot drivers: the sim driver on a mock clock, the ur_rtde driver against the UR emulator.

The ur_rtde tests run the emulator in a child process on a random 127.x.y.z address (ur_rtde's
Python calls hold the GIL while they block, so an in-process emulator would starve).
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator
from multiprocessing.connection import Connection
from typing import Any

import pytest

from emulators.ur.process import UrEmulatorProcess
from models.raster import sweep_raster
from nodes.drivers.robot import (
    MotionStatus,
    PathPoint,
    RobotConnectionError,
    RobotDriver,
    RobotDriverError,
)
from nodes.drivers.robot_sim import SimRobotDriver
from palpa.timing.clock import MockClock
from tests.procs import EMULATOR_START_S, ChildSteps, ur_emulator, wait_until

pytest.importorskip("rtde_control")
from nodes.drivers.robot_urrtde import URRtdeDriver  # noqa: E402

# the UR emulator moves in real time: its tests run one at a time on one xdist worker (make test, --dist loadgroup)
pytestmark = pytest.mark.xdist_group("ur-emulator")

OFFSET = (300.0, -40.0, 100.0)  # phantom origin in the robot base frame (mm)
HOME = (0.0, 0.0, 40.0)  # phantom frame
HOME_ARG = ",".join(str(h + o) for h, o in zip(HOME, OFFSET, strict=True)) + f",0,{math.pi},0"


def raster(n: int = 20, speed: float = 100.0) -> list[PathPoint]:
    """A boustrophedon of n waypoints over 10 mm lines, 2 mm apart, 20 mm above the table."""
    pts = []
    for i in range(n):
        line, end = divmod(i, 2)
        y = 10.0 if (line % 2 == 0) == (end == 1) else 0.0
        pts.append(PathPoint(5.0 + 2.0 * line, y, 20.0, speed, 2000.0, 0.5))
    return pts


def wait_status(driver: RobotDriver, timeout_s: float, poll_s: float = 0.005) -> list[tuple[MotionStatus, int]]:
    """Poll progress() until the status leaves MOVING; return the (status, index) changes seen."""
    seen: list[tuple[MotionStatus, int]] = []
    deadline = time.monotonic() + timeout_s
    while True:
        p = driver.progress()
        if not seen or seen[-1] != (p.status, p.index):
            seen.append((p.status, p.index))
        if p.status is not MotionStatus.MOVING:
            return seen
        if time.monotonic() > deadline:
            raise AssertionError(f"still moving after {timeout_s} s: {seen[-5:]}")
        time.sleep(poll_s)


# ------------------------------------------------------------------------------------- sim


def run_sim(poll_every_s: float, clock: MockClock, total_s: float) -> list[Any]:
    drv = SimRobotDriver(home_mm=HOME, clock=clock.now_ns, time_scale=1.0)
    drv.connect()
    drv.move_path(raster(6))
    samples = []
    t = 0.0
    while t < total_s:
        clock.advance(poll_every_s)
        t += poll_every_s
        drv.progress()
    samples.append((drv.state().pose, drv.progress()))
    return samples


def test_sim_is_deterministic_whatever_the_polling() -> None:
    a = run_sim(0.001, MockClock(), 0.9)
    b = run_sim(0.3, MockClock(), 0.9)
    assert a == b


def test_sim_runs_a_raster_plan_to_its_end_and_time_scale_speeds_it_up() -> None:
    plan = sweep_raster(5, 5, 25, 25, spacing_mm=5.0, speed_mm_s=20.0, contact_z_mm=5.0, accel_mm_s2=500.0)
    ends = {}
    for scale in (1.0, 10.0):
        clock = MockClock()
        drv = SimRobotDriver(home_mm=HOME, clock=clock.now_ns, time_scale=scale)
        drv.connect()
        drv.move_path(plan.waypoints)
        wall = 0.0
        while drv.progress().status is MotionStatus.MOVING:
            clock.advance(0.05)
            wall += 0.05
            assert wall < 10 * plan.duration_s
        assert drv.progress().index == len(plan.waypoints) - 1
        ends[scale] = (drv.state().pose, wall)
    assert ends[1.0][0] == ends[10.0][0]
    assert ends[10.0][0][:3] == pytest.approx((plan.waypoints[-1].x_mm, plan.waypoints[-1].y_mm, plan.waypoints[-1].z_mm))
    assert ends[10.0][1] == pytest.approx(ends[1.0][1] / 10, abs=0.1)


def test_sim_stop_and_latched_faults() -> None:
    clock = MockClock()
    drv = SimRobotDriver(home_mm=HOME, clock=clock.now_ns)
    drv.connect()
    drv.move_path([PathPoint(0.0, 100.0, 40.0, 50.0, 500.0)])
    clock.advance(1.0)
    drv.stop(1000.0)
    assert drv.progress().status is MotionStatus.STOPPED
    clock.advance(1.0)
    y = drv.state().pose[1]
    assert 40.0 < y < 60.0 and drv.state().speed_mm_s == (0.0,) * 6
    drv.move_path([PathPoint(0.0, 0.0, 40.0, 50.0, 500.0)])
    drv.inject_fault(MotionStatus.PROTECTIVE_STOP, "injected")
    with pytest.raises(RobotDriverError, match="protective_stop"):
        drv.move_path([PathPoint(0.0, 0.0, 40.0, 50.0, 500.0)])
    clock.advance(1.0)
    assert drv.progress().status is MotionStatus.PROTECTIVE_STOP  # latched
    drv.connect()
    assert drv.progress().status is MotionStatus.IDLE


def test_paths_over_the_caps_are_refused_naming_the_waypoint() -> None:
    drv = SimRobotDriver(home_mm=HOME, clock=MockClock().now_ns, max_speed_mm_s=50.0)
    drv.connect()
    with pytest.raises(ValueError, match="waypoint 1: speed_mm_s must be in"):
        drv.move_path([PathPoint(0, 0, 30, 10, 100), PathPoint(0, 10, 30, 80, 100)])
    with pytest.raises(RobotDriverError, match="not connected"):
        SimRobotDriver(clock=MockClock().now_ns).move_path([PathPoint(0, 0, 30, 10, 100)])


# -------------------------------------------------------------------------------- ur_rtde


@pytest.fixture
def emu(request: pytest.FixtureRequest) -> Iterator[UrEmulatorProcess]:
    args = ["--unlock-delay", "0", "--home", HOME_ARG, *getattr(request, "param", ())]
    with ur_emulator(args) as proc:
        yield proc


@pytest.fixture
def ur(emu: UrEmulatorProcess) -> Iterator[URRtdeDriver]:
    drv = URRtdeDriver(emu.host, frame_offset_mm=OFFSET, watchdog_hz=5.0, start_timeout_s=EMULATOR_START_S)
    try:
        yield drv
    finally:
        drv.close()


def emu_args(*args: str) -> pytest.MarkDecorator:
    return pytest.mark.parametrize("emu", [args], indirect=True, ids=["-".join(a.strip("-") for a in args)])


@pytest.mark.timeout(15)
@pytest.mark.system
def test_ur_driver_runs_a_raster_and_ends_where_the_sim_does(emu: UrEmulatorProcess, ur: URRtdeDriver) -> None:
    ur.connect()
    assert ur.state().pose[:3] == pytest.approx(HOME, abs=1e-6)  # phantom frame, offset removed
    path = raster(20)
    ur.move_path(path)
    seen = wait_status(ur, 10.0)
    assert seen[-1] == (MotionStatus.DONE, 19)
    indices = [i for s, i in seen if s is MotionStatus.MOVING]
    assert indices == sorted(indices) and len(set(indices)) >= 15
    base = emu.state()["pose_mm"]
    assert base[:3] == pytest.approx([path[-1].x_mm + OFFSET[0], path[-1].y_mm + OFFSET[1], path[-1].z_mm + OFFSET[2]],
                                     abs=1e-3)
    clock = MockClock()
    sim = SimRobotDriver(home_mm=HOME, clock=clock.now_ns)
    sim.connect()
    sim.move_path(path)
    while sim.progress().status is MotionStatus.MOVING:
        clock.advance(0.1)
    assert sim.progress() == ur.progress()
    deadline = time.monotonic() + 2.0  # the receive stream may trail the control one slightly
    while max(abs(a - b) for a, b in zip(ur.state().pose[:3], sim.state().pose[:3], strict=True)) > 0.1:
        assert time.monotonic() < deadline, (ur.state().pose, sim.state().pose)
        time.sleep(0.01)
    # a second path after DONE must not report the previous DONE
    ur.move_path([PathPoint(5.0, 5.0, 25.0, 50.0, 1000.0)])
    assert ur.progress().status is MotionStatus.MOVING
    assert wait_status(ur, 5.0)[-1] == (MotionStatus.DONE, 0)


@pytest.mark.timeout(15)
@emu_args("--pstop-after-waypoints", "5")
@pytest.mark.system
def test_ur_driver_reports_a_protective_stop_and_only_reconnects_when_asked(
        emu: UrEmulatorProcess, ur: URRtdeDriver) -> None:
    ur.connect()
    ur.move_path(raster(20))
    seen = wait_status(ur, 10.0)
    status, index = seen[-1]
    assert status is MotionStatus.PROTECTIVE_STOP and 4 <= index <= 6
    assert "protective stop" in ur.progress().message and "unlock" in ur.progress().message
    with pytest.raises(RobotDriverError, match="cannot move: protective_stop"):
        ur.move_path(raster(2))
    ur.stop(1000.0)  # harmless on a stopped robot
    with pytest.raises(RobotConnectionError, match="protective stop"):
        ur.connect()  # still locked
    assert ur.unlock_protective_stop() == "Protective stop releasing"  # through the dashboard
    ur.connect()
    assert ur.progress().status is MotionStatus.IDLE
    ur.move_path([PathPoint(5.0, 0.0, 30.0, 50.0, 1000.0)])
    assert wait_status(ur, 5.0)[-1] == (MotionStatus.DONE, 0)


def _driver_through_a_drop(host: str, pipe: Connection) -> None:
    """The lost-connection test's ur_rtde side, in a child process: ur_rtde has aborted the process it ran in when
    the controller dropped its connections (SIGABRT from its own reconnect thread, docs/robot.md); here an abort
    fails this test alone, not the test worker."""

    def heard(word: str) -> None:
        assert pipe.poll(20.0) and pipe.recv() == word, f"no {word!r} from the test"

    ur = URRtdeDriver(host, frame_offset_mm=OFFSET, watchdog_hz=5.0, start_timeout_s=EMULATOR_START_S)
    try:
        ur.connect()
        ur.move_path(raster(20, speed=50.0))
        pipe.send("moving")
        heard("dropped")
        seen = wait_status(ur, 5.0)
        assert seen[-1][0] is MotionStatus.DISCONNECTED, seen
        message = ur.progress().message
        assert "lost the connection" in message and "connect()" in message, message
        pipe.send("disconnected")
        heard("gone")
        assert ur.progress().status is MotionStatus.DISCONNECTED  # latched: no silent retry
        deadline = time.monotonic() + 3.0
        while True:  # once the robot is reachable again, connect() is what brings it back
            try:
                ur.connect()
                break
            except RobotConnectionError:
                assert time.monotonic() < deadline
                time.sleep(0.1)
        ur.move_path([PathPoint(5.0, 0.0, 30.0, 50.0, 1000.0)])
        assert wait_status(ur, 5.0)[-1] == (MotionStatus.DONE, 0)
        pipe.send("done")
    finally:
        ur.close()


@pytest.mark.timeout(40)
@pytest.mark.system
def test_ur_driver_reports_a_lost_connection_without_retrying(emu: UrEmulatorProcess) -> None:
    with ChildSteps(_driver_through_a_drop, emu.host, what="the driver's process") as child:
        child.said("moving", 15.0, "the driver to connect and move")
        emu.command("drop 1.0")  # every connection closed; new ones refused for 1 s
        child.tell("dropped")
        child.said("disconnected", 10.0, "the driver to report the lost connection")
        # the controller's watchdog (5 Hz) stops the program and the arm without the client
        st = emu.wait_state(lambda st: st["runtime_state"] == 1 and not st["moving"], 3.0)
        end = raster(20)[-1]
        assert math.dist(st["pose_mm"][:3], (end.x_mm + OFFSET[0], end.y_mm + OFFSET[1], end.z_mm + OFFSET[2])) > 5.0
        emu.wait_state(lambda st: st["clients"] == 0, 2.0)
        child.tell("gone")
        child.said("done", 15.0, "the driver to reconnect and move")


@pytest.mark.timeout(20)
@pytest.mark.system
def test_a_program_stopped_by_the_watchdog_is_told_from_one_stopped_by_hand(emu: UrEmulatorProcess) -> None:
    """The fault says why the control script stopped: this process stopped kicking the RTDE watchdog (a stall,
    played here by holding the driver's lock: nothing can kick), or it kicked on time and someone stopped the
    program (here the dashboard's ``stop``). The watchdog allows 1 s, so a busy machine does not make the second
    stop look like a stall."""
    ur = URRtdeDriver(emu.host, frame_offset_mm=OFFSET, watchdog_hz=1.0, start_timeout_s=EMULATOR_START_S)
    try:
        ur.connect()
        ur.move_path(raster(20, speed=50.0))
        wait_until(lambda: ur.state().speed_mm_s[1] != 0.0, 5.0, "the arm to move")
        with ur._lock:   # the stall: neither the monitor thread nor a state() call can kick
            emu.wait_state(lambda st: st["runtime_state"] == 1, 5.0)   # the controller's watchdog stopped it
            ur.state()   # the process wakes and kicks (too late) before it sees the program gone
        assert wait_status(ur, 5.0)[-1][0] is MotionStatus.FAULT
        message = ur.progress().message
        assert "RTDE watchdog: this driver did not kick it for" in message and "the 1 s it allows" in message, message
        ur.connect()   # a new program, a new watchdog: the stall is not held against it
        ur.move_path(raster(20, speed=50.0))
        wait_until(lambda: ur.state().speed_mm_s[1] != 0.0, 5.0, "the arm to move")
        with socket.create_connection((emu.host, 29999), timeout=5.0) as dash:
            dash.recv(1024)   # the banner
            dash.sendall(b"stop\n")
            assert b"Stopped" in dash.recv(1024)
        assert wait_status(ur, 5.0)[-1][0] is MotionStatus.FAULT
        message = ur.progress().message
        assert "not the RTDE watchdog: this driver kicked it at least every" in message, message
    finally:
        ur.close()


@pytest.mark.timeout(15)
@pytest.mark.system
def test_ur_driver_stop_mid_path(emu: UrEmulatorProcess, ur: URRtdeDriver) -> None:
    ur.connect()
    ur.move_path([PathPoint(5.0, 60.0, 40.0, 50.0, 1000.0)])
    deadline = time.monotonic() + 3.0
    while ur.state().speed_mm_s[1] < 45.0:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    ur.stop(500.0)
    assert ur.progress().status is MotionStatus.STOPPED
    st = emu.wait_state(lambda st: not st["moving"], 2.0)
    assert st["pose_mm"][1] - OFFSET[1] < 55.0
    assert wait_status(ur, 2.0)[-1][0] is MotionStatus.STOPPED
    # a stop is not a fault: the rest of the way is a new path from where the arm stopped (a scan resumed after a
    # pause or a hold, the next probe after a stopped one)
    ur.move_path([PathPoint(5.0, 60.0, 40.0, 50.0, 1000.0)])
    assert wait_status(ur, 5.0)[-1] == (MotionStatus.DONE, 0)
    assert emu.state()["pose_mm"][:3] == pytest.approx([5.0 + OFFSET[0], 60.0 + OFFSET[1], 40.0 + OFFSET[2]], abs=1e-3)


@pytest.mark.timeout(15)
@emu_args("--local-control")
@pytest.mark.system
def test_ur_driver_explains_a_refused_remote_control(emu: UrEmulatorProcess, ur: URRtdeDriver) -> None:
    with pytest.raises(RobotConnectionError, match="refuses remote control.*Remote Control"):
        ur.connect()


@pytest.mark.timeout(15)
def test_ur_driver_unreachable_robot() -> None:
    drv = URRtdeDriver(UrEmulatorProcess.on_random_loopback().host)
    with pytest.raises(RobotConnectionError, match="cannot reach the UR controller"):
        drv.connect()
    drv.close()


def test_a_ur_rtde_command_that_never_returns_latches_a_fault_instead_of_hanging_the_node() -> None:
    """ur_rtde's path upload waits without a deadline for the controller to run the new script (it hung a test
    run for good under load): the driver waits command_timeout_s, then faults and refuses to move."""
    import threading

    drv = URRtdeDriver("127.0.0.1", command_timeout_s=0.2)
    never = threading.Event()
    with pytest.raises(RobotDriverError, match=r"moveL\(path\) did not return within 0.2 s"):
        drv._bounded(lambda: never.wait(30), "moveL(path)")
    progress = drv.progress()
    assert progress.status == MotionStatus.FAULT and "reconnect before moving again" in progress.message
    assert drv._bounded(lambda: True, "moveL(path)") is True  # a command that returns is passed through
    with pytest.raises(RuntimeError, match="lost"):  # and its errors reach the caller as they were
        drv._bounded(lambda: (_ for _ in ()).throw(RuntimeError("RTDE connection lost")), "moveL(path)")
    never.set()


class _Path:
    """ur_rtde's async operation status: ``running`` at waypoint ``at``, or not running with the register at -1."""

    def __init__(self, running: bool, at: int = 0) -> None:
        self.running, self.at = running, at

    def isAsyncOperationRunning(self) -> bool:  # noqa: N802 - ur_rtde's names
        return self.running

    def value(self) -> int:
        return self.at if self.running else -1

    def progress(self) -> int:
        return self.at


class _Control:
    """What ur_rtde's control interface reports from its own RTDE stream."""

    def __init__(self, path: _Path, program_running: bool = True) -> None:
        self.path, self.program_running = path, program_running

    def getAsyncOperationProgressEx(self) -> _Path:  # noqa: N802
        return self.path

    def isProgramRunning(self) -> bool:  # noqa: N802
        return self.program_running


class _Receive:
    """The receive interface's stream: the controller's runtime state (2 playing, 1 stopped)."""

    def __init__(self, runtime_state: int) -> None:
        self.runtime_state = runtime_state

    def getRuntimeState(self) -> int:  # noqa: N802
        return self.runtime_state


class _Sending(_Control):
    """A control interface that takes paths (and records them) and whose register never moves."""

    def __init__(self) -> None:
        super().__init__(_Path(False))
        self.sent: list[list[list[float]]] = []

    def moveL(self, path: list[list[float]], asynchronous: bool) -> bool:  # noqa: N802
        self.sent.append(path)
        return True

    def setWatchdog(self, hz: float) -> None:  # noqa: N802
        pass


def test_a_path_that_goes_nowhere_is_done_without_being_sent() -> None:
    """A path to where the arm rests (a touch-off's rest over its first point, the arm homed there) ends within a
    tick of the controller, often before the driver reads the progress register after moveL returns; the register
    then never changed and the driver faulted "the path did not start within 10 s" (a loaded suite run)."""
    drv = URRtdeDriver("127.0.0.1", start_timeout_s=2.0)
    rc = _Sending()
    drv._rc = rc  # no receive stream: state() answers the last state, the arm at rest at the origin
    drv.move_path([PathPoint(0.0, 0.0, 0.005, 5.0, 100.0), PathPoint(0.0, 0.0, 0.0, 5.0, 100.0)])
    assert not rc.sent and drv.progress().status is MotionStatus.DONE and drv.progress().index == 1
    drv.move_path([PathPoint(0.0, 0.0, 0.005, 5.0, 100.0), PathPoint(0.0, 0.0, 1.0, 5.0, 100.0)])
    assert len(rc.sent) == 1 and drv.progress().status is MotionStatus.MOVING  # one that goes somewhere is sent
    drv.move_path([PathPoint(0.0, 0.0, 0.0, 5.0, 100.0)])
    assert len(rc.sent) == 2, "a path to where the arm is while it moves is sent: it replaces the move"


def moving_driver(start_timeout_s: float = 2.0, command_timeout_s: float = 10.0,
                  clock: MockClock | None = None) -> URRtdeDriver:
    """A driver as move_path leaves it (no robot: its status is driven through _poll_path by fake interfaces), on
    ``clock`` (the node's, which times the path's start)."""
    clock = clock or MockClock()
    drv = URRtdeDriver("127.0.0.1", start_timeout_s=start_timeout_s, command_timeout_s=command_timeout_s,
                       clock=clock.now_ns)
    drv._status, drv._moving, drv._reg0, drv._count = MotionStatus.MOVING, True, -1, 20
    drv._t_move = clock.now_ns()
    return drv


def test_a_kick_gap_near_the_watchdog_s_limit_is_told_as_the_watchdog() -> None:
    """The controller times a kick from its arrival, the driver from its sending: a loaded run stopped by the
    watchdog when the driver had measured 0.99 s of its 1 s (the test above), and was told 'not the watchdog'."""
    clock = MockClock()
    drv = URRtdeDriver("127.0.0.1", watchdog_hz=1.0, clock=clock.now_ns)  # kicks are timed on the node's clock
    now = clock.now_ns()
    for gap, watchdog in ((1.2, True), (0.99, True), (0.91, True), (0.85, False), (0.3, False)):
        drv._watchdog.last_kick, drv._watchdog.kick_gap = now - 100_000_000, round(gap * 1e9)
        cause = drv._stop_cause(now)
        assert cause.startswith("RTDE watchdog") is watchdog and f"{gap:.2f} s" in cause, (gap, cause)
    drv._watchdog.kick_gap = 990_000_000
    assert "within 0.1 s of the 1 s it allows" in drv._stop_cause(now)
    drv._watchdog.kick_gap = 1_200_000_000
    assert "over the 1 s it allows" in drv._stop_cause(now)
    clock.advance(1.5)  # and a stall since the last kick counts, read on the same clock
    assert drv._stop_cause().startswith("RTDE watchdog: this driver did not kick it for 1.60 s")


def test_a_path_the_controller_never_starts_latches_a_fault_after_the_start_timeout() -> None:
    """The start is timed on the node's clock: what the wall clock does meanwhile (a busy machine) does not count."""
    clock = MockClock()
    drv = moving_driver(start_timeout_s=2.0, clock=clock)
    clock.advance(1.9)
    drv._poll_path(_Control(_Path(False)), _Receive(2))
    assert drv.progress().status is MotionStatus.MOVING  # not yet: 1.9 s < 2 s
    clock.advance(0.2)
    drv._poll_path(_Control(_Path(False)), _Receive(2))
    progress = drv.progress()
    assert progress.status is MotionStatus.FAULT and "did not start within 2 s" in progress.message


def test_a_script_stop_is_reported_only_once_the_receive_stream_shows_it_too() -> None:
    """The control stream shows the script gone mid-path before the receive stream, whose safety bits say why: the
    driver waits for the receive stream (a protective stop must not be reported as a stopped script)."""
    drv = moving_driver()
    drv._poll_path(_Control(_Path(True, 4), program_running=False), _Receive(2))
    assert drv.progress().status is MotionStatus.MOVING and drv._index == 4
    drv._poll_path(_Control(_Path(True, 4), program_running=False), _Receive(1))
    progress = drv.progress()
    assert progress.status is MotionStatus.FAULT and "control script stopped" in progress.message
    drv = moving_driver(command_timeout_s=0.0)  # a receive stream that never catches up: reported all the same
    drv._poll_path(_Control(_Path(True, 4), program_running=False), _Receive(2))
    assert drv.progress().status is MotionStatus.FAULT


class _BurstingReceive:
    """ur_rtde's receive interface answering each getter from the latest package, while a burst of packages (after
    a stall) comes in: one more per call for the first ``burst`` calls. Package n: z = n mm, Fz = n N."""

    def __init__(self, burst: int) -> None:
        self.package, self.burst = 0, burst

    def _next(self) -> int:
        if self.burst > 0:
            self.burst -= 1
            self.package += 1
        return self.package

    def getTimestamp(self) -> float:  # noqa: N802 - ur_rtde's name
        return self._next() * 0.002

    def getActualTCPPose(self) -> list[float]:  # noqa: N802
        return [0.0, 0.0, self._next() / 1000, 0.0, math.pi, 0.0]

    def getActualTCPSpeed(self) -> list[float]:  # noqa: N802
        return [0.0] * 6

    def getActualTCPForce(self) -> list[float]:  # noqa: N802
        return [0.0, 0.0, float(self._next()), 0.0, 0.0, 0.0]


@pytest.mark.parametrize("burst", [0, 3, 8])
def test_the_ur_state_is_one_package_s_even_while_packages_burst_in(burst: int) -> None:
    pose, _, force = URRtdeDriver._snapshot(_BurstingReceive(burst))
    assert pose[2] * 1000 == pytest.approx(force[2])  # pose and force from the same package


class _Kicked:
    """A control interface that counts the watchdog's kicks."""

    def __init__(self) -> None:
        self.kicks = 0

    def kickWatchdog(self) -> None:  # noqa: N802 - ur_rtde's name
        self.kicks += 1


def test_the_watchdog_is_kicked_four_times_per_period_of_the_node_s_clock_and_at_once_if_it_steps_back() -> None:
    """The node's clock is the wall's on the rig (it can step back, NTP): a kick is never held back by a clock that
    went backwards, or the controller would starve meanwhile."""
    now = [10_000_000_000]
    drv = URRtdeDriver("127.0.0.1", watchdog_hz=2.0, clock=lambda: now[0])
    rc = _Kicked()
    for _ in range(101):  # 1 s in 10 ms steps: a kick at the first step 125 ms or more after the last (130 ms)
        drv._kick(rc)
        now[0] += 10_000_000
    assert rc.kicks == 8
    now[0] -= 3_600_000_000_000  # an hour back
    drv._kick(rc)
    drv._kick(rc)
    assert rc.kicks == 9
