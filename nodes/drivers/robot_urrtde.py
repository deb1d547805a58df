"""Universal Robots driver over ur_rtde (RTDEControlInterface + RTDEReceiveInterface).

Frames and units: callers speak the phantom frame in mm; the robot speaks its base frame in m.
``frame_offset_mm`` is the phantom origin in the base frame (axes assumed parallel), and the
tool is held at the fixed orientation ``tool_rotvec`` (rad, base frame).

Paths go out as one asynchronous ``moveL(path)`` (ur_rtde re-uploads its control script with
one movel per waypoint); progress comes from the script's async progress register. A monitor
thread polls the robot every ``poll_s`` and kicks an RTDE watchdog: if this process stalls or
the link drops, the controller stops the program (and so the arm) within ``1/watchdog_hz`` s.
The kicks are timed on the clock handed in (the node's), which is the controller's too: the wall
for a robot, the graph's for an emulated controller stepped on it (nodes.drivers.rtde_watchdog).

``interfaces`` makes the two interfaces: ur_rtde's by default; emulators.ur.local's stand-ins run
an emulated controller in process on the node's clock (no thread of theirs moves between calls,
so the driver starts no monitor thread either: its caller's progress() and state() poll and kick).

Faults are latched, reported through progress() with a message, and never retried silently:
a protective stop, a lost connection, or a control script that stopped under us all end the
motion, and only ``connect()`` (called by the user) connects again. ur_rtde's control
interface does try one reconnect of its own when its stream breaks; the receive interface
does not, so the driver treats a dead receive stream as the loss of the robot whatever the
control interface managed meanwhile. Why a connect() failed is worded in nodes.drivers.rtde_errors.

Beware: ur_rtde's Python calls hold the GIL while they block (connect ~50 ms, a path upload
~20-50 ms, disconnect 1 s); other threads of the process stall meanwhile.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Sequence
from typing import Any

from nodes.drivers.host_clock import host_ns
from nodes.drivers.native_stderr import native_stderr
from nodes.drivers.robot import (
    MotionStatus,
    PathPointLike,
    PathProgress,
    RobotDriverError,
    TcpState,
    Vec6,
    checked_path,
)
from nodes.drivers.rtde_errors import control_refused, in_protective_stop, unreachable
from nodes.drivers.rtde_interfaces import RtdeInterfaces, UrRtde
from nodes.drivers.rtde_watchdog import RtdeWatchdog

__all__ = ["RtdeInterfaces", "URRtdeDriver"]

log = logging.getLogger(__name__)

_LATCHED = (MotionStatus.PROTECTIVE_STOP, MotionStatus.DISCONNECTED, MotionStatus.FAULT)
_RECEIVE_FIELDS = ["timestamp", "actual_TCP_pose", "actual_TCP_speed", "actual_TCP_force", "robot_mode",
                   "safety_mode", "runtime_state", "robot_status_bits", "safety_status_bits"]
_SAFETY_MODES_OK = (1, 2)  # NORMAL, REDUCED
_RUNTIME_PLAYING = 2  # RTDE runtime_state
_ARRIVED_MM = 0.01
"""A path whose every waypoint is this close to a TCP at rest (under 1 mm/s) goes nowhere: it is done without being
sent (move_path)."""


def _vec6(values: Sequence[float]) -> Vec6:
    v = [float(x) for x in values]
    return (v[0], v[1], v[2], v[3], v[4], v[5])


class URRtdeDriver:
    """RobotDriver for a UR e-Series arm at `host` (see module docstring)."""

    def __init__(self, host: str, *, frame_offset_mm: Sequence[float] = (0.0, 0.0, 0.0),
                 tool_rotvec: Sequence[float] = (0.0, math.pi, 0.0), frequency_hz: float = 500.0,
                 watchdog_hz: float | None = 2.0, max_speed_mm_s: float = 250.0,
                 max_accel_mm_s2: float = 2500.0, poll_s: float = 0.01, start_timeout_s: float = 2.0,
                 command_timeout_s: float = 10.0, clock: Callable[[], int] = host_ns,
                 interfaces: RtdeInterfaces | None = None) -> None:
        if len(frame_offset_mm) != 3 or len(tool_rotvec) != 3:
            raise ValueError(f"URRtdeDriver: frame_offset_mm and tool_rotvec need 3 numbers each, "
                             f"got {frame_offset_mm!r}, {tool_rotvec!r}")
        if watchdog_hz is not None and not (math.isfinite(watchdog_hz) and watchdog_hz > 0):
            raise ValueError(f"URRtdeDriver: watchdog_hz must be > 0 or None, got {watchdog_hz!r}")
        self.host = host
        self.offset = (float(frame_offset_mm[0]), float(frame_offset_mm[1]), float(frame_offset_mm[2]))
        self.tool_rotvec = (float(tool_rotvec[0]), float(tool_rotvec[1]), float(tool_rotvec[2]))
        self.frequency_hz, self.watchdog_hz = frequency_hz, watchdog_hz
        self.max_speed_mm_s, self.max_accel_mm_s2 = max_speed_mm_s, max_accel_mm_s2
        self.poll_s, self.start_timeout_s, self.command_timeout_s = poll_s, start_timeout_s, command_timeout_s
        self._clock = clock
        self._interfaces: RtdeInterfaces = interfaces if interfaces is not None else UrRtde()
        self._lock = threading.RLock()  # serialises every ur_rtde call
        self._rc: Any = None  # rtde_control.RTDEControlInterface
        self._rr: Any = None  # rtde_receive.RTDEReceiveInterface
        self._monitor: threading.Thread | None = None
        self._halt = threading.Event()
        self._status, self._index, self._message = MotionStatus.IDLE, 0, ""
        self._count = 0
        self._moving = False
        self._started = False
        self._script_gone: int | None = None
        """When (clock ns) the control stream first showed the script stopped mid-path."""
        self._reg0 = 0
        self._t_move = 0
        """When (clock ns) the current path was sent: its start is timed on the clock handed in (the node's), so
        that on a simulated clock a busy machine cannot fail a start that simulated time has not yet reached."""
        self._stop_requested = False
        self._watchdog = RtdeWatchdog(watchdog_hz, clock)
        self._last = TcpState(0, (0.0,) * 6, (0.0,) * 6, (0.0,) * 6)  # stamp 0: never read

    # ------------------------------------------------------------ connection
    def connect(self) -> None:
        """Connect to the robot and start the control script (ur_rtde uploads it).

        Raises RobotConnectionError naming the cause: unreachable, remote control disabled,
        protective stop still active, or ur_rtde missing."""
        self._teardown()
        with self._lock:
            try:
                with native_stderr() as said:  # ur_rtde prints 'connect: Connection refused': into the one line
                    self._rr = self._interfaces.receive(self.host, self.frequency_hz, _RECEIVE_FIELDS)
            except RuntimeError as e:
                raise unreachable(self.host, "RTDE port 30004", str(e), said) from e
            if self._rr.isProtectiveStopped():
                self._teardown_locked()
                raise in_protective_stop(self.host)
            try:
                with native_stderr() as said:
                    self._rc = self._interfaces.control(self.host, self.frequency_hz)
            except RuntimeError as e:
                self._teardown_locked()
                raise control_refused(self.host, str(e), said) from e
            self._set_watchdog()
            self._status, self._index, self._message = MotionStatus.IDLE, 0, ""
            self._moving = self._stop_requested = False
        self._halt.clear()
        if self._interfaces.threaded:
            self._monitor = threading.Thread(target=self._monitor_loop, name=f"ur-monitor-{self.host}", daemon=True)
            self._monitor.start()
        log.info("connected to the UR at %s", self.host)

    def close(self) -> None:
        """Stop the control script (which stops any motion) and disconnect. Never raises."""
        self._teardown()

    # ----------------------------------------------------------------- state
    def state(self) -> TcpState:
        with self._lock:
            rr = self._rr
            if rr is None or not rr.isConnected():
                return self._last
            try:
                pose, speed, force = self._snapshot(rr)
                if self._rc is not None and self._status not in _LATCHED:
                    self._kick(self._rc)  # also from here: whichever thread is busiest keeps it fed
            except RuntimeError:
                return self._last
            o = self.offset
            self._last = TcpState(
                self._clock(),
                (pose[0] * 1000 - o[0], pose[1] * 1000 - o[1], pose[2] * 1000 - o[2], pose[3], pose[4], pose[5]),
                (speed[0] * 1000, speed[1] * 1000, speed[2] * 1000, speed[3], speed[4], speed[5]),
                _vec6(force))
            return self._last

    @staticmethod
    def _snapshot(rr: Any) -> tuple[Sequence[float], Sequence[float], Sequence[float]]:
        """Pose, speed and force from one RTDE package. ur_rtde answers each getter from the latest package, and
        its receive thread can take a new one between two calls (several when the stream bursts after a stall), so
        a force was paired with a pose up to ~10 cycles apart: 0.1 mm at a touch-off's 5 mm/s. The controller's
        timestamp before and after tells; read again (at most twice) if a package came in between."""
        for _ in range(3):
            t0 = rr.getTimestamp()
            pose, speed, force = rr.getActualTCPPose(), rr.getActualTCPSpeed(), rr.getActualTCPForce()
            if rr.getTimestamp() == t0:
                break
        return pose, speed, force

    def progress(self) -> PathProgress:
        with self._lock:
            self._poll()
            return PathProgress(self._status, self._index, self._message)

    # -------------------------------------------------------------- commands
    def move_path(self, points: Sequence[PathPointLike]) -> None:
        st = self.state()
        start = st.pose[:3]
        path = checked_path(points, self.max_speed_mm_s, self.max_accel_mm_s2, (start[0], start[1], start[2]))
        o, r = self.offset, self.tool_rotvec
        ur_path = [[(p.x_mm + o[0]) / 1000, (p.y_mm + o[1]) / 1000, (p.z_mm + o[2]) / 1000, r[0], r[1], r[2],
                    p.speed_mm_s / 1000, p.accel_mm_s2 / 1000, p.blend_mm / 1000] for p in path]
        with self._lock:
            self._poll()
            if self._rc is None:
                raise RobotDriverError(f"UR at {self.host}: not connected; call connect() first")
            if self._status in _LATCHED:
                raise RobotDriverError(f"UR at {self.host}: cannot move: {self._status.value}: {self._message}")
            still = not self._moving and math.hypot(*st.speed_mm_s[:3]) < _ARRIVED_MM * 100
            if still and all(math.dist((p.x_mm, p.y_mm, p.z_mm), start) <= _ARRIVED_MM for p in path):
                # already there: a path that goes nowhere ends within a tick or two of the controller, often before
                # the progress register can be read after moveL returns, and would then look never started
                self._count, self._index, self._moving = len(path), len(path) - 1, False
                self._status, self._message = MotionStatus.DONE, "already at the path's end: nothing sent"
                return
            ok = self._bounded(lambda: self._rc.moveL(ur_path, True), "moveL(path)")
            if not ok:
                self._poll()
                if self._status not in _LATCHED:
                    self._latch(MotionStatus.FAULT, "the controller did not accept the path (ur_rtde moveL returned "
                                f"false; program running: {self._rc.isProgramRunning()})")
                raise RobotDriverError(f"UR at {self.host}: path refused: {self._message}")
            self._reg0 = self._rc.getAsyncOperationProgressEx().value()
            self._set_watchdog()  # the path came with a freshly uploaded script
            self._count, self._index = len(path), 0
            self._moving, self._started, self._stop_requested, self._script_gone = True, False, False, None
            self._t_move = self._clock()
            self._status, self._message = MotionStatus.MOVING, ""

    def _bounded(self, call: Callable[[], bool], what: str) -> bool:
        """``call()`` (a blocking ur_rtde command), waited for at most ``command_timeout_s``: ur_rtde's path
        upload waits without a deadline for the controller to run the new script, and has been seen to wait for
        good (a loaded machine, the script upload racing the previous one). A command that does not come back
        latches FAULT and raises; its thread is left behind (a C++ call cannot be interrupted) and the driver
        refuses further motion until it is connected again."""
        result: list[bool] = []
        error: list[BaseException] = []

        def run() -> None:
            try:
                result.append(bool(call()))
            except BaseException as e:  # noqa: BLE001 - handed to the caller's thread as it was
                error.append(e)

        worker = threading.Thread(target=run, name=f"ur-{what}", daemon=True)
        worker.start()
        worker.join(self.command_timeout_s)
        if error:
            raise error[0]
        if worker.is_alive():
            reason = f"ur_rtde {what} did not return within {self.command_timeout_s:g} s"
            self._latch(MotionStatus.FAULT, f"{reason}; the arm is stopped by the controller's watchdog: "
                        "reconnect before moving again")
            raise RobotDriverError(f"UR at {self.host}: {reason}")
        return result[0]

    def stop(self, decel_mm_s2: float) -> None:
        decel = decel_mm_s2 if math.isfinite(decel_mm_s2) and decel_mm_s2 > 0 else self.max_accel_mm_s2
        with self._lock:
            rc = self._rc
            if rc is None or self._status in _LATCHED:
                return
            try:
                rc.stopL(decel / 1000, True)
            except RuntimeError as e:
                log.warning("UR at %s: stopL failed: %s", self.host, e)
            if self._moving:
                self._stop_requested = True
                self._status, self._message = MotionStatus.STOPPED, f"stopped by request (stopL at {decel:g} mm/s^2)"

    def unlock_protective_stop(self) -> str:
        """Ask the controller's dashboard to unlock a protective stop; returns its answer. Only
        after the cause has been found; then call connect()."""
        import dashboard_client

        db = dashboard_client.DashboardClient(self.host)
        db.connect()
        try:
            db.unlockProtectiveStop()
            return "Protective stop releasing"
        except RuntimeError as e:
            return str(e)
        finally:
            db.disconnect()

    # -------------------------------------------------------------- internals
    def _latch(self, status: MotionStatus, message: str) -> None:
        where = f" (the path was at waypoint {self._index} of {self._count})" if self._moving else ""
        self._status, self._message = status, f"{message}{where}"
        self._moving = False
        log.error("UR at %s: %s: %s", self.host, status.value, self._message)

    def _poll(self) -> None:
        """Update the status from the robot (lock held). Latched states are final."""
        rr, rc = self._rr, self._rc
        if rr is None or rc is None or self._status in _LATCHED:
            return
        try:
            if not rr.isConnected() or not rc.isConnected():
                wd = f"; its watchdog stops the program within {1 / self.watchdog_hz:.2g} s" if self.watchdog_hz else ""
                self._latch(MotionStatus.DISCONNECTED,
                            f"lost the connection to the UR at {self.host} (RTDE stream ended){wd}; "
                            "not reconnecting: call connect() once the robot is reachable")
                return
            if rr.isProtectiveStopped():
                self._latch(MotionStatus.PROTECTIVE_STOP,
                            f"protective stop on the UR at {self.host}: the robot stopped; find the cause, unlock it "
                            "on the teach pendant, then connect() again")
                return
            if rr.isEmergencyStopped() or rr.getSafetyMode() not in _SAFETY_MODES_OK:
                self._latch(MotionStatus.FAULT, f"UR at {self.host} in safety mode {rr.getSafetyMode()} "
                                                "(emergency stop or safety fault)")
                return
            if self._moving:
                self._poll_path(rc, rr)
            self._kick(rc)
        except RuntimeError as e:
            self._latch(MotionStatus.FAULT, f"ur_rtde error while polling the UR at {self.host}: {e}")

    def _poll_path(self, rc: Any, rr: Any) -> None:
        st = rc.getAsyncOperationProgressEx()
        running = st.isAsyncOperationRunning()
        # the register may still show the previous operation right after moveL returned;
        # any change of it (or a running flag) means ours has started
        self._started = self._started or running or st.value() != self._reg0
        if not self._started:
            if self._clock() - self._t_move > self.start_timeout_s * 1e9:
                self._latch(MotionStatus.FAULT, f"the path did not start within {self.start_timeout_s:g} s")
            return
        if running:
            self._index = max(0, min(st.progress(), self._count - 1))
            if not rc.isProgramRunning():
                # the control and receive interfaces read two streams: until the receive one shows the program
                # stopped too, its safety bits may not yet say why (a protective stop is checked before this)
                now = self._clock()
                self._script_gone = self._script_gone or now
                if rr.getRuntimeState() == _RUNTIME_PLAYING and now - self._script_gone < self.command_timeout_s * 1e9:
                    return
                self._latch(MotionStatus.FAULT, "the control script stopped on the controller while moving "
                                                f"({self._stop_cause()})")
            return
        self._moving = False
        if self._stop_requested:
            self._message = "stopped by request; the move was cancelled"
        else:
            self._status, self._index = MotionStatus.DONE, self._count - 1

    def _kick(self, rc: Any) -> None:
        """Kick the RTDE watchdog if it is due (RtdeWatchdog.kick)."""
        self._watchdog.kick(rc)

    def _set_watchdog(self) -> None:
        if self._rc is not None:
            self._watchdog.arm(self._rc)

    def _stop_cause(self, now: int | None = None) -> str:
        """Why the program may have stopped: the watchdog starved or not (RtdeWatchdog.stop_cause)."""
        return self._watchdog.stop_cause(now)

    def _monitor_loop(self) -> None:
        while not self._halt.wait(self.poll_s):
            with self._lock:
                if self._rc is None:
                    return
                self._poll()

    def _teardown(self) -> None:
        self._halt.set()
        monitor, self._monitor = self._monitor, None
        if monitor is not None and monitor is not threading.current_thread():
            monitor.join(5.0)
        with self._lock:
            self._teardown_locked()

    def _teardown_locked(self) -> None:
        """Stop the script (which stops any motion) and drop both interfaces. ur_rtde's
        destructors disconnect (0.5 s each); calling disconnect() too would wait twice."""
        rc, rr, self._rc, self._rr = self._rc, self._rr, None, None
        if rc is not None:
            try:
                if rc.isConnected():
                    rc.stopScript()
            except RuntimeError as e:
                log.warning("UR at %s: stopping the control script: %s", self.host, e)
            if self._status not in _LATCHED and self._moving:
                self._status, self._message, self._moving = MotionStatus.STOPPED, "driver closed during the motion", False
        del rc, rr  # the last references: both interfaces disconnect here
