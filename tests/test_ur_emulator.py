"""The UR controller emulator, driven by the real ur_rtde client and by raw protocol clients.

ur_rtde's Python calls hold the GIL while they block, so every test that uses ur_rtde runs
the emulator in a child process (UrEmulatorProcess) on its own random 127.x.y.z address.
Protocol-level tests without ur_rtde run the emulator in-process with OS-chosen ports.
"""

from __future__ import annotations

import math
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from emulators.clock_file import ClockWriter
from emulators.ur import ControllerConfig, FaultPlan, UrController, UrEmulator
from emulators.ur.controller import BACKING_N_PER_MM
from emulators.ur.process import UrEmulatorProcess
from emulators.ur.rtde import RtdeSession
from emulators.ur.script import ScriptReceiver, parse_path
from models.arm import ArmTarget
from models.phantom import load_phantom
from models.world import TissueWorld
from tests.procs import ChildSteps, ur_emulator, wait_until

# the UR emulator moves in real time: its tests run one at a time on one xdist worker (make test, --dist loadgroup)
pytestmark = [pytest.mark.system, pytest.mark.xdist_group("ur-emulator")]

REPO = Path(__file__).resolve().parent.parent


def test_the_group_is_in_effect_under_loadgroup(request: pytest.FixtureRequest) -> None:
    """Under ``--dist loadgroup`` (make test) xdist marks a grouped test's id with its group, and schedules by
    that: a pytest that no longer takes the mark (pytest 9.2 with xdist 3.8 did so silently) fails here instead of
    letting the UR tests starve each other on three workers."""
    if not getattr(request.config.option, "loadgroup", False):  # set in an xdist worker under --dist loadgroup
        pytest.skip("not in a pytest-xdist worker under --dist loadgroup")
    assert request.node.nodeid.endswith("@ur-emulator"), request.node.nodeid


rtde_control = pytest.importorskip("rtde_control")
rtde_receive = pytest.importorskip("rtde_receive")

DOWN = math.pi
HOME_M = (0.3, 0.0, 0.3, 0.0, DOWN, 0.0)


def random_host() -> str:
    return UrEmulatorProcess.on_random_loopback().host


@pytest.fixture
def emu(request: pytest.FixtureRequest) -> Iterator[UrEmulatorProcess]:
    """A fresh emulator process; extra CLI flags by indirect parametrisation."""
    args = ["--unlock-delay", "0", *getattr(request, "param", ())]
    with ur_emulator(args) as proc:
        yield proc


def emu_args(*args: str) -> pytest.MarkDecorator:
    return pytest.mark.parametrize("emu", [args], indirect=True, ids=["-".join(a.strip("-") for a in args)])


class Clients:
    """ur_rtde receive + control interfaces, always disconnected at the end."""

    def __init__(self, host: str, control: bool = True) -> None:
        self.r: Any = rtde_receive.RTDEReceiveInterface(host)
        self.c: Any = rtde_control.RTDEControlInterface(host) if control else None

    def close(self) -> None:
        """ur_rtde's destructors disconnect (0.5 s each); calling disconnect() too would wait twice."""
        self.c = self.r = None


@pytest.fixture
def clients(emu: UrEmulatorProcess) -> Iterator[Clients]:
    cl = Clients(emu.host)
    try:
        yield cl
    finally:
        cl.close()


def reached(pose: list[float], target: list[float], tol_m: float = 1e-4) -> bool:
    """Position within tol_m (0.1 mm) of the target."""
    return max(abs(a - b) for a, b in zip(pose[:3], target[:3], strict=True)) < tol_m


def raster(n: int = 20, speed: float = 0.1, accel: float = 2.0, blend: float = 0.0005) -> list[list[float]]:
    """n waypoints of a boustrophedon over 10 mm lines 2 mm apart, starting 20 mm below home
    (ur_rtde path rows: x, y, z, rx, ry, rz in m and rad, speed, acceleration, blend)."""
    path = []
    for i in range(n):
        line, end = divmod(i, 2)
        y = 0.01 if (line % 2 == 0) == (end == 1) else 0.0
        path.append([0.3 + 0.002 * line, y, 0.28, 0.0, DOWN, 0.0, speed, accel, blend if i < n - 1 else 0.0])
    return path


# --------------------------------------------------------------------------------- with ur_rtde


@pytest.mark.timeout(15)
def test_connect_and_moveL_reaches_the_pose(emu: UrEmulatorProcess, clients: Clients) -> None:
    assert clients.r.getActualTCPPose() == pytest.approx(list(HOME_M))
    assert clients.c.isProgramRunning()
    target = [0.32, 0.015, 0.26, 0.0, DOWN, 0.0]
    assert clients.c.moveL(target, 0.1, 0.5)  # synchronous: returns once the move is done
    assert emu.state()["pose_mm"][:3] == pytest.approx([320.0, 15.0, 260.0], abs=1e-6)
    # the receive interface has its own stream, which may trail the control one by a few packages
    wait_until(lambda: reached(clients.r.getActualTCPPose(), target), 2.0, "the streamed pose to arrive")


@pytest.mark.timeout(15)
def test_raster_path_of_20_waypoints_reports_progress(emu: UrEmulatorProcess, clients: Clients) -> None:
    path = raster(20)
    assert clients.c.moveL(path, True)  # asynchronous
    seen: list[int] = []
    wait_until(lambda: clients.c.getAsyncOperationProgress() >= 0, 2.0, "the path to start")
    while (p := clients.c.getAsyncOperationProgress()) >= 0:
        if not seen or seen[-1] != p:
            seen.append(p)
        time.sleep(0.002)
    assert seen == sorted(seen) and seen[0] == 0 and seen[-1] == 19
    assert len(seen) >= 15  # 10 mm lines at 100 mm/s: each waypoint is current for tens of ms
    assert emu.state()["pose_mm"][:3] == pytest.approx([v * 1000 for v in path[-1][:3]], abs=1e-6)
    wait_until(lambda: reached(clients.r.getActualTCPPose(), path[-1]), 2.0, "the streamed pose to arrive")
    assert clients.c.getAsyncOperationProgressEx().isAsyncOperationRunning() is False


@pytest.mark.timeout(15)
@emu_args("--pstop-after-waypoints", "5")
def test_protective_stop_mid_path_is_seen_by_the_client(emu: UrEmulatorProcess, clients: Clients) -> None:
    path = raster(20)
    assert clients.c.moveL(path, True)
    wait_until(clients.r.isProtectiveStopped, 5.0, "the protective stop")
    assert clients.r.getSafetyStatusBits() & (1 << 2)
    # the control client reads its own RTDE stream, which may carry the stopped program a cycle (2 ms) later
    wait_until(lambda: not clients.c.isProgramRunning(), 2.0, "the control client to see the program stop")
    wait_until(lambda: emu.state()["moving"] is False, 2.0, "the arm to stop")
    stopped_at = clients.r.getActualTCPPose()
    assert stopped_at[:3] != pytest.approx(path[-1][:3], abs=1e-3)
    assert 4 <= emu.state()["path_index"] <= 6
    # the controller refuses motion until the stop is unlocked; then the script runs again
    assert clients.c.moveL([0.3, 0.0, 0.3, 0.0, DOWN, 0.0], 0.1, 1.0) is False
    assert emu.command("unlock")["reply"] == "Protective stop releasing"
    assert clients.c.reuploadScript()
    wait_until(clients.c.isProgramRunning, 2.0, "the control script to run again")
    assert clients.c.moveL([0.3, 0.0, 0.3, 0.0, DOWN, 0.0], 0.1, 1.0)


@pytest.mark.timeout(15)
@emu_args("--local-control")
def test_dashboard_refusing_remote_control_is_a_clear_error(emu: UrEmulatorProcess) -> None:
    with pytest.raises(RuntimeError, match="enable remote control"):
        rtde_control.RTDEControlInterface(emu.host)
    assert emu.command("program")["source"] == ""  # refused before any script was sent


def _client_through_a_drop(host: str, pipe: Any) -> None:
    """The ur_rtde side of :func:`test_reconnect_after_a_dropped_connection`, in a process of its own: ur_rtde's own
    reconnect thread has aborted its process on a broken pipe (docs/robot.md; twice in one loaded suite run, which
    took the test worker down and left the run hanging). Here that fails this test with its cause, and only it."""
    clients = Clients(host)
    pipe.send("connected")
    assert pipe.recv() == "dropped"
    wait_until(lambda: not clients.r.isConnected(), 3.0, "the receive interface to notice")
    wait_until(lambda: not clients.c.isConnected(), 3.0, "the control interface to give up")
    pipe.send("noticed")
    assert pipe.recv() == "gone"   # the emulator has no client left
    deadline = time.monotonic() + 3.0
    while True:  # the refusal window is short; retry until it has passed
        try:
            assert clients.r.reconnect()
            break
        except RuntimeError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    assert clients.c.reconnect()
    assert clients.c.moveL([0.31, 0.0, 0.3, 0.0, DOWN, 0.0], 0.1, 1.0)
    wait_until(lambda: reached(clients.r.getActualTCPPose(), [0.31, 0.0, 0.3]), 2.0, "the new pose")
    clients.close()
    pipe.send("done")


@pytest.mark.timeout(30)
def test_reconnect_after_a_dropped_connection(emu: UrEmulatorProcess) -> None:
    with ChildSteps(_client_through_a_drop, emu.host, what="the ur_rtde client") as child:
        child.said("connected", 10.0, "the client to connect")
        emu.command("drop 0.5")  # close every connection and refuse new ones for 0.5 s
        child.tell("dropped")
        child.said("noticed", 10.0, "the client to notice")
        emu.wait_state(lambda st: st["clients"] == 0, 2.0)
        child.tell("gone")
        child.said("done", 10.0, "the client to reconnect and move")


@pytest.mark.timeout(15)
def test_short_streaming_pause_is_tolerated_and_the_watchdog_stops_the_program(
        emu: UrEmulatorProcess, clients: Clients) -> None:
    t0 = clients.r.getTimestamp()
    emu.command("pause 0.5")
    wait_until(lambda: clients.r.getTimestamp() > t0 + 0.6, 3.0, "the stream to resume")
    assert clients.r.isConnected() and clients.c.isConnected()
    assert clients.c.setWatchdog(10.0)  # then never kicked: the program must stop within 0.1 s
    wait_until(lambda: not clients.c.isProgramRunning(), 2.0, "the watchdog to stop the program")
    assert any("watchdog" in m for m in emu.command("messages")["messages"])


@pytest.mark.timeout(30)
def test_on_a_clock_file_the_arm_holds_while_that_clock_stands_and_the_controller_answers_meanwhile(
        tmp_path: Path) -> None:
    """``--clock-file`` (emulators.clock_file): the arm moves only as far as the clock's time plus the lead allows,
    whatever the wall clock does; the controller meanwhile runs, so a path upload (which waits for the new script
    to play) is answered while the clock stands; released, the arm runs on the wall clock again."""
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--clock-file", str(writer.path), "--clock-lead", "0.05"]) as emu:
            clients = Clients(emu.host)
            try:
                t0 = time.time_ns()
                writer.write(t0)
                start = emu.state()
                # the lead (25 steps) is spent at rest, then the arm holds while the controller's ticks go on
                held = emu.wait_state(lambda st: st["ticks"] > start["ticks"] + 100, 5.0)["arm_steps"]
                assert held <= start["arm_steps"] + 25
                assert clients.c.moveL([0.3, 0.1, 0.3, 0.0, DOWN, 0.0], 0.05, 1.0, True)  # answered though held
                st = emu.wait_state(lambda st: st["ticks"] > start["ticks"] + 300, 5.0)
                assert st["arm_steps"] == held and st["pose_mm"][1] == pytest.approx(0.0, abs=1e-9), st
                assert st["runtime_state"] == 2  # the new script plays; the arm waits for the clock
                writer.write(t0 + 100_000_000)  # 0.1 s: 50 steps, from rest at 1 m/s^2 up to 50 mm/s
                moved = emu.wait_state(lambda st: st["arm_steps"] >= held + 50, 5.0)
                st = emu.wait_state(lambda st: st["ticks"] > moved["ticks"] + 100, 5.0)
                assert st["arm_steps"] == held + 50, st
                assert 2.5 < st["pose_mm"][1] < 4.5, st  # 1.25 mm accelerating, then ~0.05 s at 50 mm/s
                writer.release()
                emu.wait_state(lambda st: st["pose_mm"][1] > 99.9 and not st["moving"], 10.0)
            finally:
                clients.close()
    finally:
        writer.close()


@pytest.mark.timeout(15)
def test_stopL_decelerates_an_async_move(emu: UrEmulatorProcess, clients: Clients) -> None:
    assert clients.c.moveL([0.3, 0.1, 0.3, 0.0, DOWN, 0.0], 0.1, 1.0, True)
    wait_until(lambda: clients.r.getActualTCPSpeed()[1] > 0.09, 2.0, "cruising speed")
    y0 = emu.state()["pose_mm"][1]
    clients.c.stopL(2.0)  # 0.1 m/s at 2 m/s^2: 2.5 mm to rest (returns at rest)
    st = emu.wait_state(lambda st: not st["moving"], 2.0)
    assert 1.0 < st["pose_mm"][1] - y0 < 10.0  # ~2.5 mm plus what the call's latency allows
    assert st["pose_mm"][1] < 90.0


@pytest.mark.timeout(15)
def test_speedL_then_speedStop(emu: UrEmulatorProcess, clients: Clients) -> None:
    assert clients.c.speedL([0.0, 0.05, 0.0, 0.0, 0.0, 0.0], 0.5)  # realtime command: returns at once
    emu.wait_state(lambda st: st["speed"][1] == pytest.approx(50.0), 2.0)
    assert clients.c.speedStop(1.0)  # synchronous: returns at rest
    st = emu.state()
    assert not st["moving"] and st["speed"] == [0.0] * 6 and st["pose_mm"][1] > 2.5  # >= 0.1 s ramp + 0.05 s stop


@pytest.mark.timeout(15)
def test_upper_range_registers(emu: UrEmulatorProcess) -> None:
    flags = rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT | rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS
    c = rtde_control.RTDEControlInterface(emu.host, -1.0, flags)
    try:
        assert c.moveL([0.3, 0.02, 0.3, 0.0, DOWN, 0.0], 0.1, 1.0)
        assert emu.state()["pose_mm"][1] == pytest.approx(20.0, abs=1e-6)
    finally:
        del c  # ur_rtde's destructor disconnects


# ------------------------------------------------------------------------ without ur_rtde


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        assert chunk, "connection closed"
        buf += chunk
    return buf


def rtde_call(sock: socket.socket, msg_type: bytes, payload: bytes = b"") -> tuple[bytes, bytes]:
    sock.sendall(struct.pack(">HB", 3 + len(payload), msg_type[0]) + payload)
    return rtde_read(sock)


def rtde_read(sock: socket.socket) -> tuple[bytes, bytes]:
    size, kind = struct.unpack(">HB", _recv_exact(sock, 3))
    return bytes([kind]), _recv_exact(sock, size - 3)


@pytest.fixture
def inproc() -> Iterator[UrEmulator]:
    emulator = UrEmulator(random_host(), dashboard_port=0, script_port=0, rtde_port=0, log=lambda m: None)
    with emulator:
        yield emulator
    assert emulator.threads_alive() == []


@pytest.mark.timeout(10)
def test_rtde_protocol_types_recipe_ids_and_500_hz_stream(inproc: UrEmulator) -> None:
    with socket.create_connection((inproc.host, inproc.ports["rtde"]), timeout=5) as s:
        assert rtde_call(s, b"V", struct.pack(">H", 2)) == (b"V", b"\x01")
        kind, body = rtde_call(s, b"v")
        assert kind == b"v" and struct.unpack(">IIII", body)[:2] == (5, 11)
        kind, body = rtde_call(s, b"O", struct.pack(">d", 500.0) + b"timestamp,no_such_field,")
        assert body[0] == 0 and body[1:].decode().split(",") == ["DOUBLE", "NOT_FOUND"]
        names = b"timestamp,runtime_state,actual_TCP_pose,safety_status_bits,output_int_register_0,"
        kind, body = rtde_call(s, b"O", struct.pack(">d", 500.0) + names)
        assert body[0] == 1 and body[1:].decode().split(",") == ["DOUBLE", "UINT32", "VECTOR6D", "UINT32", "INT32"]
        ids = [rtde_call(s, b"I", f"input_int_register_{i},input_double_register_{i},".encode())[1][0] for i in range(3)]
        assert ids == [1, 2, 3]
        s.sendall(struct.pack(">HB", 3 + 1 + 12, ord("U")) + struct.pack(">Bid", 2, 7, 0.5))  # writes reg 1
        assert rtde_call(s, b"S") == (b"S", b"\x01")
        stamps: list[float] = []
        while len(stamps) < 20:
            kind, body = rtde_read(s)
            if kind == b"U":
                values = struct.unpack(">BdI6dIi", body)
                assert values[0] == 1 and values[2] == 1 and values[3:6] == pytest.approx((0.3, 0.0, 0.3))
                stamps.append(values[1])
        # whole 2 ms ticks apart, in order (one per tick when the emulator keeps up: test_rtde_recipes_stream_...)
        steps = [(b - a) / 0.002 for a, b in zip(stamps, stamps[1:], strict=False)]
        assert all(s > 0.5 and abs(s - round(s)) < 1e-6 for s in steps), steps
    with inproc.controller.lock:
        assert inproc.controller.in_int[1] == 7 and inproc.controller.in_double[1] == 0.5


def test_rtde_recipes_stream_one_package_per_period_of_controller_ticks() -> None:
    """At 500 Hz an output recipe is due every 2 ms tick, at 250 Hz every other one, in the controller's own ticks
    (a stalled emulator catching up sends what is due then, not a burst of stale packages)."""
    session = RtdeSession((5, 11, 1, 0), lambda name: lambda: 0.0, lambda names, values: None, lambda m: None)
    session.handle(ord("V"), struct.pack(">H", 2), 0)
    ids = [session.handle(ord("O"), struct.pack(">d", hz) + b"timestamp,", 0)[0][3] for hz in (500.0, 250.0)]
    assert ids == [1, 2]
    assert session.due_packages(1) == []  # not started
    session.handle(ord("S"), b"", 0)
    due = [[p[3] for p in session.due_packages(tick)] for tick in range(1, 9)]
    assert due == [[1, 2], [1], [1, 2], [1], [1, 2], [1], [1, 2], [1]]
    assert [p[3] for p in session.due_packages(100)] == [1, 2]  # 92 ticks late: one of each, not 92
    assert [[p[3] for p in session.due_packages(tick)] for tick in (101, 102, 103)] == [[1, 2], [1], [1, 2]]


@pytest.mark.timeout(10)
def test_dashboard_replies_and_local_control(inproc: UrEmulator) -> None:
    with socket.create_connection((inproc.host, inproc.ports["dashboard"]), timeout=5) as s:
        f = s.makefile("rw", newline="\n")
        assert "Dashboard Server" in f.readline()

        def ask(cmd: str) -> str:
            f.write(cmd + "\n")
            f.flush()
            return f.readline().strip()

        assert "5.11" in ask("PolyscopeVersion")
        assert ask("get serial number").isdigit()
        assert ask("is in remote control") == "true"
        assert ask("safetystatus") == "Safetystatus: NORMAL"
        inproc.protective_stop("test")
        assert ask("safetymode") == "Safetymode: PROTECTIVE_STOP"
        assert ask("unlock protective stop").startswith("Cannot unlock protective stop until 5s")
        inproc.set_remote_control(False)
        assert ask("is in remote control") == "false"
        assert "not allowed" in ask("stop")
        assert ask("robotmode") == "Robotmode: RUNNING"  # read-only commands still answer
        assert ask("bogus").startswith("could not understand")
        assert ask("quit") == "Disconnected"


def test_unlock_waits_for_the_configured_delay() -> None:
    ctl = UrController(ControllerConfig(unlock_delay_s=0.1))
    ctl.protective_stop("test")
    assert ctl.unlock_protective_stop().startswith("Cannot unlock protective stop")
    for _ in range(60):
        ctl.tick()
    assert ctl.unlock_protective_stop() == "Protective stop releasing" and not ctl.protective_stopped


class BareSurface:
    """A plane 10 mm above the table with no tissue model: the emulator must treat it as rigid."""

    def surface_z(self, x_mm: float, y_mm: float) -> float:
        return 10.0


def test_contact_force_is_the_tissue_world_s_and_the_force_limit_protective_stops() -> None:
    """The emulated TCP force is models.world's FE-grounded force (no estimator formula); pressed past the world's
    tables the specimen has bottomed out on the table, and the force limit trips the protective stop."""
    phantom = load_phantom(REPO / "phantoms" / "flat_26k.yaml")  # 20 mm thick: the surface at z = 20
    cfg = ControllerConfig(home_pose=(20.0, 20.0, 22.0, 0.0, DOWN, 0.0), force_limit_n=1.0, force_noise_n=0.0,
                           force_bias_n=0.0)  # a perfect sensor: actual_TCP_force is the contact force
    ctl = UrController(cfg, phantom=phantom)
    ctl.tick()
    assert ctl.force[2] == 0.0  # 2 mm above the surface
    ctl.arm.move_l((20.0, 20.0, 19.0, 0.0, DOWN, 0.0), 20.0, 400.0)  # 1 mm into the tissue
    for _ in range(200):
        ctl.tick()
    world = TissueWorld(phantom)
    expected = float(world.force_n(20.0, 20.0, 1.0, indenter_radius_mm=cfg.tip_radius_mm))
    assert 0.05 < expected < 1.0
    assert ctl.force[2] == pytest.approx(expected, rel=1e-9)
    assert ctl.output("actual_TCP_force")[2] == pytest.approx(expected)  # type: ignore[index]
    ctl.arm.move_l((20.0, 20.0, 0.0, 0.0, DOWN, 0.0), 20.0, 400.0)  # press on: bottoms out, the force limit trips
    for _ in range(1500):
        ctl.tick()
    deepest = float(world.deepest_mm(20.0, 20.0, indenter_radius_mm=cfg.tip_radius_mm))
    assert ctl.protective_stopped and not ctl.arm.is_moving
    assert 20.0 - deepest - 0.5 < ctl.arm.pose[2] < 20.0 - deepest  # within half a mm of bottoming out
    assert any("exceeds the 1 N limit" in m for m in ctl.messages)


def test_the_force_sensor_reads_the_contact_force_off_by_its_bias_and_noise_until_zeroed() -> None:
    """actual_TCP_force is what a UR's sensor reads: the contact force plus an offset (up to force_bias_n, from the
    seed) and white noise (force_noise_n per 2 ms sample); zero_ftsensor() takes the reading now as the zero; the
    force limit acts on the contact force itself."""
    phantom = load_phantom(REPO / "phantoms" / "flat_26k.yaml")

    def readings(seed: int, zero: bool = False) -> tuple[float, np.ndarray]:
        cfg = ControllerConfig(home_pose=(20.0, 20.0, 19.0, 0.0, DOWN, 0.0), force_noise_n=0.5, force_bias_n=3.0,
                               sensor_seed=seed)
        ctl = UrController(cfg, phantom=phantom)
        ctl.tick()
        if zero:
            ctl.zero_ft_sensor()
        out = []
        for _ in range(2000):
            ctl.tick()
            out.append(ctl.output("actual_TCP_force"))
        return ctl.force[2], np.asarray(out, dtype=float)

    true_fz, r = readings(1)
    assert 0.05 < true_fz < 1.0  # 1 mm into the tissue
    bias = r[:, :3].mean(axis=0) - (0.0, 0.0, true_fz)
    assert np.all(np.abs(bias) < 3.0) and np.max(np.abs(bias)) > 0.3  # off by its offset
    assert np.allclose(r[:, :3].std(axis=0), 0.5, rtol=0.1)  # and noisy
    assert np.allclose(r[:, 3:], 0.0)
    _, again = readings(1)
    assert np.array_equal(again, r)  # deterministic for a seed
    _, other = readings(2)
    assert np.max(np.abs(other[:, :3].mean(axis=0) - r[:, :3].mean(axis=0))) > 0.3  # another sensor
    _, zeroed = readings(1, zero=True)
    # zeroed, up to the noise of the one reading taken as the zero (seed 1's offset is over 1.5 N on x and y)
    assert np.all(np.abs(zeroed[:, :3].mean(axis=0)) < 1.5) and np.max(np.abs(bias[:2])) > 1.5


def test_a_spring_sample_pushes_back_as_its_spring() -> None:
    phantom = load_phantom(REPO / "phantoms" / "ref_spring_010.yaml")
    top = float(phantom.surface_z(20.0, 20.0))
    cfg = ControllerConfig(home_pose=(20.0, 20.0, top + 1.0, 0.0, DOWN, 0.0), force_limit_n=100.0)
    ctl = UrController(cfg, phantom=phantom)
    ctl.arm.move_l((20.0, 20.0, top - 0.5, 0.0, DOWN, 0.0), 20.0, 400.0)
    for _ in range(200):
        ctl.tick()
    k = float(phantom.spring_constant(20.0, 20.0, cfg.tip_radius_mm, 0.5))
    assert 0 < k < BACKING_N_PER_MM and ctl.force[2] == pytest.approx(0.5 * k, rel=1e-6)


def test_a_surface_without_tissue_is_rigid() -> None:
    cfg = ControllerConfig(home_pose=(20.0, 20.0, 11.0, 0.0, DOWN, 0.0), force_limit_n=100.0)
    ctl = UrController(cfg, phantom=BareSurface())
    ctl.arm.move_l((20.0, 20.0, 9.99, 0.0, DOWN, 0.0), 20.0, 400.0)
    for _ in range(200):
        ctl.tick()
    assert ctl.force[2] == pytest.approx(0.01 * BACKING_N_PER_MM, rel=1e-6)


def test_fault_plan_fires_once_timed_from_the_first_motion() -> None:
    ctl = UrController()
    ctl.arm_faults(FaultPlan(pstop_at_s=0.1, pause_stream_at_s=0.05, pause_stream_for_s=0.2))
    for _ in range(100):
        ctl.tick()
    assert not ctl.protective_stopped  # nothing moved yet
    ctl.start_motion([ArmTarget((350.0, 0.0, 300.0, 0.0, DOWN, 0.0), 50.0, 500.0)])
    for _ in range(30):
        ctl.tick()
    assert ctl.ticks < ctl.stream_paused_until
    for _ in range(30):
        ctl.tick()
    assert ctl.protective_stopped and ctl.faults is not None and ctl.faults.fired == {"pause", "pstop_t"}


def test_a_stop_command_left_for_the_replaced_program_does_not_stop_the_new_one() -> None:
    """ur_rtde stops its script (command 255 in input register 0) and uploads the next one: the new program starts
    with that command still in the register when the client's clear has not been read yet (the emulator's threads
    on a busy machine). It must run, and stop on a stop command written for it."""
    ctl = UrController(ControllerConfig(program_start_s=0.002))
    ctl.write_inputs(["input_int_register_0"], [255])  # for the program being replaced
    ctl.submit_program("def rtde_control():\n    global reg_offset_int = # int register offset\n0\nend\n")
    for _ in range(10):
        ctl.tick()
    assert ctl.program is not None and ctl.out_int[0] == 1  # playing, ready for a command
    ctl.write_inputs(["input_int_register_0"], [255])
    for _ in range(2):
        ctl.tick()
    assert ctl.program is None and "rtde_control: received stop script" in ctl.messages[-2]


def test_script_receiver_and_injected_path_parsing() -> None:
    rx = ScriptReceiver()
    text = ("def rtde_control():\n    global reg_offset_float = # float register offset\n24    global x = 1\n"
            "    def exec_move_path():\n        # inject move path\n\tsignal_async_progress(0)\n"
            "\tmovel(p[0.3,1e-05,-0.2,0,3.14159,0],a=1.2,v=0.25,r=0)\n\tsignal_async_progress(1)\n"
            "\tmovel(p[0.31,0.01,0.2,0,3.14159,0],a=1.2,v=0.25,r=0.002)\n    end\nend\nstopl(2)\n")
    units = [u for i in range(0, len(text), 7) for u in rx.feed(text[i:i + 7])]  # arrives in pieces
    assert [k for k, _ in units] == ["program", "statement"] and units[1][1] == "stopl(2)"
    moves = parse_path(units[0][1])
    assert [m.values[1] for m in moves] == [1e-05, 0.01] and moves[1].r == 0.002 and moves[0].v == 0.25


@pytest.mark.timeout(10)
def test_cli_reports_a_busy_address_and_exits_1(inproc: UrEmulator) -> None:
    cmd = [sys.executable, "-m", "emulators.ur", "--host", inproc.host, "--dashboard-port", str(inproc.ports["dashboard"]),
           "--script-port", "0", "--rtde-port", "0"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=8)
    assert res.returncode == 1
    assert f"cannot listen on {inproc.host}:{inproc.ports['dashboard']} (dashboard)" in res.stderr
