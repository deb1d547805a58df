"""Robot scanner node: plans a raster over the phantom, checks it against the safety limits, drives the arm
along it and reports progress; exits 0 when the scan is complete (so a launch can make it ``required``).

Safety is enforced here whatever the driver: a plan that leaves the workspace box or exceeds the speed or
acceleration cap is refused before any motion (naming the waypoint); while moving, a watchdog stops the arm when
the probe's data goes stale (``watch_topic``), ``pressure/state`` reports a fault or goes quiet, and ``robot/estop``
stops it at once. Stale data ends a scan as a fault; a probe (a service call) fails instead, with the reason, and
the scanner stays up and refuses the next probe until the data is fresh again. A path the arm's driver refuses ends
a scan as a fault with the driver's reason (a probe fails with it). The arm's pose is published on
``robot/pose``; the plan, latched, on ``robot/plan`` before motion.

Services (nodes.scanner.scan_control): ``scanner/probe_at`` probes one point and answers with the stiffness found there;
``scanner/pause``, ``scanner/resume`` and ``scanner/abort`` control a scan or a probe. With ``autostart: false``
the scanner does not scan but waits, idle, for probe requests; with a touch-off set it finds the surface first,
and probes then follow the found surface as a scan's lines would (sweep: the working offset; indent: the press depth
below it).

This module holds the node: its inputs, its state and the actions on the arm (run a path, pause, resume, halt, follow
the path). Its states and every change between them are one table, nodes.scanner.states; its parameters are in
nodes.scanner.scanner_params; the plan and its checks against the workspace box and caps in nodes.scanner.scan_plan;
the periodic supervision pass (watchdogs, the box, the arm's status, the start-up, the touch-off, holds for stale data)
in nodes.scanner.scan_supervision. Each collaborator gets what it needs of the node as a Protocol of its own, and none
imports this module.
"""

from __future__ import annotations

import math
from typing import cast

import palpa
from messages import (
    EStop,
    IndenterDisplacements,
    PlanWaypoint,
    PressureState,
    ProbeAt,
    ProbeHeights,
    ProbeResult,
    RobotPose,
    ScanPlan,
    ScanStatus,
    StiffnessSample,
    TableHeight,
    Trigger,
    TriggerResult,
)
from messages.robot import ScanState
from models.following import FollowConfig
from models.raster import RasterPlan, Waypoint
from nodes.drivers.robot import (
    MotionStatus,
    PathProgress,
    RobotConnectionError,
    RobotDriver,
    RobotDriverError,
)
from nodes.scanner.scan_control import ScanControl
from nodes.scanner.scan_plan import check_path, path_segments, plan_raster
from nodes.scanner.scan_progress import PathProgressMeter
from nodes.scanner.scan_supervision import SUPERVISION_MAX_S, ScanSupervision, supervision_period_s
from nodes.scanner.scanner_params import ScannerParams
from nodes.scanner.specimen import SpecimenPlanner
from nodes.scanner.states import ON_PATH, Event, ScanStateMachine, State
from nodes.scanner.surface_follow import LineFollower
from palpa.targets import TargetError, load_object

# SUPERVISION_MAX_S and supervision_period_s: importable from here as before the split (nodes.scanner.scan_supervision)
__all__ = ["SUPERVISION_MAX_S", "RobotScanner", "supervision_period_s"]

_STOPPING_FAULTS = {"device_lost", "over_pressure", "tracking_error"}


class RobotScanner(palpa.Node):
    """Raster scan with a safety envelope."""

    Params = ScannerParams
    params: ScannerParams

    def setup(self) -> None:
        p = self.params
        self.pose_pub = self.publisher("robot/pose", RobotPose)
        self.plan_pub = self.publisher("robot/plan", ScanPlan, latched=True)
        self.table_pub = self.publisher("scanner/table", TableHeight, latched=True)
        self.status_pub = self.publisher("robot/scan_status", ScanStatus, latched=True)
        self.machine = ScanStateMachine()  # every change of state goes through its table (nodes.scanner.states)
        self.message = ""
        self.end_code = 0
        """The exit code of the latest end (finish)."""
        self.last_probe_ns: int | None = None
        self.last_pressure_ns: int | None = None
        self.segments: list[tuple[int, int]] = []
        self.segment = 0
        self.hold_until_ns: int | None = None
        self.started_ns = self.clock.now_ns()
        self.driver: RobotDriver = self.closing(self._make_driver())  # closed even if the plan is refused below
        try:
            self.driver.connect()
        except RobotConnectionError as exc:  # an expected failure (robot off, wrong host): one line, no traceback
            raise palpa.PalpaError(f"{self.name}: {' '.join(str(exc).split())}") from None
        # refuses a specimen that does not fit, before any motion
        self.specimen = SpecimenPlanner(p, self.name, self.driver)
        self.follower: LineFollower | None = None
        if p.mode == "sweep" and p.touchoff != "off" and p.watch_topic == "probe/heights" and p.follow_gain_per_s > 0:
            self.follower = LineFollower(FollowConfig(target_gap_mm=p.working_offset_mm,
                                                      gain_per_s=p.follow_gain_per_s,
                                                      max_offset_mm=p.follow_max_offset_mm),
                                         (p.workspace_mm[2], p.workspace_mm[5]))
        self.plan = self.make_plan()
        self.path: tuple[Waypoint, ...] = self.plan.waypoints
        self.meter = PathProgressMeter(self.plan.waypoints, self.plan.duration_s)
        self.check_plan()  # raises before any motion
        self.resume_index = 0
        self.control = ScanControl(self)
        self.control.probe = self.service("scanner/probe_at", ProbeAt, ProbeResult, self.control.on_probe_at)
        self.service("scanner/pause", Trigger, TriggerResult, self.control.on_pause)
        self.service("scanner/resume", Trigger, TriggerResult, self.control.on_resume)
        self.service("scanner/abort", Trigger, TriggerResult, self.control.on_abort)
        self.subscribe("stiffness/sample", StiffnessSample, self.control.on_sample)
        if p.autostart:
            self.publish_plan()
        if p.watch_topic == "probe/heights":
            self.subscribe("probe/heights", ProbeHeights, self.on_probe)
        elif p.watch_topic == "camera/indenters":
            self.subscribe("camera/indenters", IndenterDisplacements, self.on_probe)
        self.subscribe("pressure/state", self.on_pressure)
        self.subscribe("robot/estop", self.on_estop)
        # serving probe_at too, the scanner is idle only once it could probe: the probe's data flows and the
        # surface is found (a request before that would only be refused)
        if p.autostart or self.specimen.touch is not None or p.watch_topic:
            self.change(Event.WAIT, f"waiting for probe data on {p.watch_topic}" if p.watch_topic else "")
        else:
            self.change(Event.SERVE, "waiting for scanner/probe_at requests")
        self.timer(1.0 / p.pose_rate_hz, self.publish_pose, first_in_s=0.0)
        self.supervision = ScanSupervision(self)
        self.timer(supervision_period_s(p.pose_rate_hz), self.supervision.supervise)
        self.timer(0.2, self.publish_status)

    # -- planning --------------------------------------------------------------------------------
    def _make_driver(self) -> RobotDriver:
        p = self.params
        if p.driver == "sim":
            from nodes.drivers.robot_sim import SimRobotDriver

            return SimRobotDriver(home_mm=tuple(p.home_mm), clock=self.clock.now_ns, time_scale=p.time_scale)
        from nodes.drivers.robot_urrtde import RtdeInterfaces, URRtdeDriver

        interfaces: RtdeInterfaces | None = None
        if p.rtde_interfaces:
            try:
                interfaces = cast(RtdeInterfaces, load_object(p.rtde_interfaces))
            except TargetError as exc:
                raise palpa.ParamError(f"{self.name}: rtde_interfaces: {exc}") from None
        # the poses it reads are stamped by the node's clock, like the sim arm's (the probe's samples are matched to
        # them by stamp: a graph on another clock than the wall's, e.g. a test harness's, must not see a gap)
        return URRtdeDriver(p.robot_host, frame_offset_mm=tuple(p.frame_offset_mm),
                            tool_rotvec=tuple(p.tool_rotvec), watchdog_hz=p.rtde_watchdog_hz or None,
                            clock=self.clock.now_ns, interfaces=interfaces)

    def make_plan(self) -> RasterPlan:
        """The scan's raster from the parameters over the specimen (nodes.scanner.scan_plan)."""
        return plan_raster(self.params, self.specimen, self.follower is not None)

    def check_plan(self) -> None:
        """Refuse a plan (and the path from the current pose to it) that leaves the box or exceeds a cap."""
        self.check_path(self.plan.waypoints)
        self.segments = path_segments(self.plan.waypoints, self.follower is not None)

    def check_path(self, waypoints: tuple[Waypoint, ...]) -> None:
        """Raise ParamError naming the first waypoint that leaves the workspace box or exceeds a cap (and when
        the arm itself is outside the box): nodes.scanner.scan_plan.check_path."""
        check_path(waypoints, self.params, self.name, self.driver)

    def publish_plan(self) -> None:
        p, plan = self.params, self.plan
        self.plan_pub.publish(ScanPlan(
            stamp_ns=self.clock.now_ns(), mode=plan.mode, region_mm=self.specimen.region,
            spacing_mm=plan.line_spacing_mm, speed_mm_s=p.speed_mm_s, lines=plan.line_count,
            estimated_duration_s=plan.duration_s,
            waypoints=[PlanWaypoint(x_mm=w.x_mm, y_mm=w.y_mm, z_mm=w.z_mm, speed_mm_s=w.speed_mm_s, kind=w.kind,
                                    line=w.line, hold_s=w.hold_s) for w in plan.waypoints],
        ))
        self.log.info("plan: %s, %d lines, %d waypoints, ~%.0f s", plan.mode, plan.line_count,
                      len(plan.waypoints), plan.duration_s)

    def publish_table(self) -> None:
        """The table's height, once the table touch found it (``table_point_mm``), latched on ``scanner/table``."""
        z, at = self.specimen.table_z_mm, self.specimen.table_point
        if z is not None and at is not None:
            self.table_pub.publish(TableHeight(stamp_ns=self.clock.now_ns(), x_mm=at[0], y_mm=at[1], z_mm=z))

    def scan(self, plan: RasterPlan) -> None:
        """Publish ``plan`` (already checked) as the scan's plan and drive it."""
        self.plan = plan
        self.publish_plan()
        self.run_path(plan, Event.SCAN)

    # -- inputs ----------------------------------------------------------------------------------
    def on_probe(self, msg: ProbeHeights | IndenterDisplacements) -> None:
        self.last_probe_ns = self.clock.now_ns()
        if self.status is State.TOUCHING:
            self.specimen.on_probe(msg)
        elif self.follower is not None and self.status is State.SCANNING and isinstance(msg, ProbeHeights):
            self.follower.on_heights(msg.stamp_ns, msg.h_mm, msg.valid)

    def on_pressure(self, msg: PressureState) -> None:
        self.last_pressure_ns = self.clock.now_ns()
        bad = _STOPPING_FAULTS.intersection(msg.faults)
        if bad and self.machine.can(Event.FAULT):
            self.halt(Event.FAULT, f"pressure fault {', '.join(sorted(bad))}")

    def on_estop(self, msg: EStop) -> None:
        if msg.engaged and self.machine.can(Event.ESTOP):
            self.halt(Event.ESTOP, f"e-stop: {msg.reason or 'engaged'}")

    # -- state -----------------------------------------------------------------------------------
    @property
    def status(self) -> State:
        """The scanner's state (nodes.scanner.states)."""
        return self.machine.state

    @property
    def state(self) -> ScanState:
        """The state's name as published on ``robot/scan_status``."""
        return self.machine.state.wire

    def can(self, event: Event) -> bool:
        """Whether ``event`` changes the state now (the table's guard)."""
        return self.machine.can(event)

    def change(self, event: Event, message: str = "") -> State:
        """Change the state by ``event`` (raises IllegalTransition if the table has no such change) and say so."""
        to = self.machine.fire(event)
        self.message = message
        self.publish_status()
        return to

    # -- running ---------------------------------------------------------------------------------
    def stale_data(self, now: int) -> str:
        """Why the data the arm moves on is stale, or '' while it is fresh: the probe's topic silent past the
        watchdog, or ``pressure/state`` silent once it has been heard."""
        p = self.params
        if p.watch_topic and self.last_probe_ns is not None and (now - self.last_probe_ns) / 1e9 > p.watchdog_s:
            return f"probe data on {p.watch_topic} stale for more than {p.watchdog_s * 1000:.0f} ms"
        if p.pressure_watchdog_s > 0 and self.last_pressure_ns is not None and \
                (now - self.last_pressure_ns) / 1e9 > p.pressure_watchdog_s:
            return (f"pressure/state silent for more than {p.pressure_watchdog_s * 1000:.0f} ms "
                    "(the pressure controller died?)")
        return ""

    def stop_arm(self) -> None:
        """Stop the arm where it is at the acceleration cap (the state is the caller's to change)."""
        self.driver.stop(self.params.max_accel_mm_s2)

    def halt(self, event: Event, why: str) -> None:
        """Stop the arm now and end the scan by ``event`` (fault, estop, abort, the arm stopping by itself)."""
        try:
            self.stop_arm()
        finally:
            self.control.fail_probe(f"the scanner stopped: {why}")
            to = self.machine.fire(event)
            self.log.error("STOP (%s): %s", to.wire, why)
            self.message = why
            self.publish_status()
            self.finish(1 if to is State.FAULT else 2)

    def finish(self, code: int) -> None:
        """End the node after ``linger_s`` with exit ``code``; a later end (an e-stop while done) replaces the code,
        so the first linger's exit reports it."""
        self.end_code = code
        self.timer(self.params.linger_s, lambda: self.request_shutdown(self.end_code), oneshot=True)

    def run_path(self, plan: RasterPlan, event: Event) -> None:
        """Drive ``plan`` (already checked) from where the arm is, by ``event`` (SCAN, PROBE)."""
        self.path = plan.waypoints
        self.segments = path_segments(plan.waypoints, self.follower is not None and event is Event.SCAN)
        self.segment = 0
        self.hold_until_ns = None
        self.meter = PathProgressMeter(plan.waypoints, plan.duration_s)
        self.change(event)
        self.start_segment()

    def pause(self, event: Event, why: str = "") -> None:
        """Stop the arm where it is (by ``event``: PAUSE, HOLD); :meth:`resume` goes on towards the waypoint it was
        heading for."""
        was = self.state
        self.stop_arm()
        self.resume_index = self.driver.progress().index
        self.change(event, why or f"paused during {was}")

    def resume(self) -> None:
        a, b = self.segments[self.segment]
        a = min(a + self.resume_index, b)
        self.segments[self.segment] = (a, b)
        self.hold_until_ns = None
        self.change(Event.RESUME)
        self._send(a, b)

    def start_segment(self) -> None:
        if self.segment >= len(self.segments) and self.status is State.PROBING:
            self.meter.complete()
            self.control.path_done()
            return
        if self.segment >= len(self.segments):
            self.meter.complete()
            holds = self.supervision.holds
            held = f" (held {holds} time(s) for stale data)" if holds else ""
            self.change(Event.COMPLETE,
                        f"scan complete in {(self.clock.now_ns() - self.started_ns) / 1e9:.1f} s{held}")
            if self.follower is not None:
                self.log.info("surface following: %d corrections, the largest %+.2f mm", self.follower.resends,
                              self.follower.largest_mm)
            self.log.info("scan complete")
            self.finish(0)
            return
        a, b = self.segments[self.segment]
        if self.follower is not None and self.status is State.SCANNING:
            self.follower.start_line(self.path[a : b + 1], self.path[b].line, self.specimen.plan_z())
        self._send(a, b)

    def _send(self, a: int, b: int) -> bool:
        """Drive path[a..b] (the current line's heights at the follower's offset while scanning); False when the
        arm's driver refused it (a probe then fails, a scan ends as a fault: both with the driver's reason)."""
        pts = self.path[a : b + 1]
        scanning = self.status is State.SCANNING
        if self.follower is not None and scanning:
            pts = self.follower.shifted(pts)
        try:
            self.driver.move_path(pts)
        except (ValueError, RobotDriverError) as exc:
            if self.status is State.PROBING:
                self.control.driver_refused(exc)
            else:
                self.halt(Event.FAULT, f"the arm's driver refused the scan's path: {exc}")
            return False
        return True

    def follow_path(self, prog: PathProgress, tcp: tuple[float, float, float], now: int) -> None:
        """One supervision pass along the path (after its checks): progress, the probe's measuring window, the
        surface follower's corrections, the holds at press points and the next segment."""
        seg_start, seg_end = self.segments[self.segment]
        self.meter.update(seg_start + prog.index, tcp)
        if self.status is State.PROBING:
            self.control.track(seg_start + prog.index, now)
        if self.follower is not None and self.status is State.SCANNING and prog.status == MotionStatus.MOVING:
            self.follower.track(self.path, seg_start + prog.index)
            if self.follower.due(now):
                self.resend(self.follower, seg_start + prog.index, seg_end, now)
                return
        if self.hold_until_ns is not None:
            if now >= self.hold_until_ns:
                self.hold_until_ns = None
                self.segment += 1
                self.start_segment()
            return
        if prog.status == MotionStatus.DONE:
            hold = self.path[seg_end].hold_s
            if hold > 0:
                self.hold_until_ns = now + int(hold * 1e9)
            else:
                self.segment += 1
                self.start_segment()
        elif prog.status == MotionStatus.STOPPED:
            self.halt(Event.ARM_STOPPED, prog.message or "the arm stopped")

    @property
    def on_path(self) -> bool:
        """The arm follows a path with a segment still to drive or to finish."""
        return self.status in ON_PATH and self.segment < len(self.segments)

    def resend(self, follower: LineFollower, i: int, b: int, now: int) -> None:
        """Surface following: the rest of the line (from the waypoint being approached) again, at the new offset,
        after the same checks as the plan (box, caps)."""
        try:
            self.check_path(follower.shifted(self.path[i : b + 1]))
        except palpa.ParamError as exc:
            self.halt(Event.FAULT, f"surface following: {exc}")
            return
        self.segments[self.segment] = (i, b)
        if self._send(i, b):
            follower.sent(now)

    # -- outputs ---------------------------------------------------------------------------------
    def publish_pose(self) -> None:
        st = self.driver.state()
        x, y, z, rx, ry, rz = st.pose
        if self.specimen.touch is not None:
            self.specimen.touch.note_pose(st.stamp_ns, x, y, z)
        if self.follower is not None:
            self.follower.note_pose(st.stamp_ns, x, y, z)
        sx, sy, sz = st.speed_mm_s[:3]
        self.pose_pub.publish(RobotPose(stamp_ns=st.stamp_ns, x_mm=x, y_mm=y, z_mm=z, rx_rad=rx, ry_rad=ry,
                                        rz_rad=rz, speed_mm_s=math.sqrt(sx * sx + sy * sy + sz * sz),
                                        force_z_n=st.force_n[2]))

    def publish_status(self) -> None:
        self.status_pub.publish(ScanStatus(
            stamp_ns=self.clock.now_ns(), state=self.state, line=self.meter.line, lines=self.plan.line_count,
            progress=self.meter.progress, eta_s=self.meter.eta_s, message=self.message,
        ))

    def on_shutdown(self) -> None:
        if self.status is not State.DONE:
            self.stop_arm()  # the driver is closed after this (closing() in setup)


if __name__ == "__main__":
    palpa.run_node(RobotScanner)
