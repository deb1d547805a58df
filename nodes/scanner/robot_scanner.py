"""Robot scanner node: plans a raster over the phantom, checks it against the safety limits, drives the arm
along it and reports progress; exits 0 when the scan is complete (so a launch can make it ``required``).

Safety is enforced here whatever the driver: a plan that leaves the workspace box or exceeds the speed or
acceleration cap is refused before any motion (naming the waypoint); while moving, a watchdog stops the arm when
the probe's data goes stale (``watch_topic``), ``pressure/state`` reports a fault or goes quiet, and ``robot/estop``
stops it at once. Stale data ends a scan as a fault; a probe (a service call) fails instead, with the reason, and
the scanner stays up and refuses the next probe until the data is fresh again. The arm's pose is published on
``robot/pose``; the plan, latched, on ``robot/plan`` before motion.

Services (nodes.scanner.scan_control): ``scanner/probe_at`` probes one point and answers with the stiffness found there;
``scanner/pause``, ``scanner/resume`` and ``scanner/abort`` control a scan or a probe. With ``autostart: false``
the scanner does not scan but waits, idle, for probe requests; with a touch-off set it finds the surface first,
and probes then follow the found surface as a scan's lines would (sweep: the working offset; indent: the press depth
below it).

This module holds the node: its parameters, its inputs, its state and the actions on the arm (run a path, pause,
resume, halt). The plan and its checks against the workspace box and caps are in nodes.scanner.scan_plan; the periodic
supervision pass (watchdogs, the box, the arm's status, advancing the path) in nodes.scanner.scan_supervision.
"""

from __future__ import annotations

import math
from typing import Literal

import palpa
from messages import (
    EStop,
    IndenterDisplacements,
    PlanWaypoint,
    PressureState,
    ProbeHeights,
    RobotPose,
    ScanPlan,
    ScanStatus,
)
from messages.robot import ScanState
from models.following import FollowConfig
from models.raster import RasterPlan, Waypoint
from nodes.drivers.robot import RobotConnectionError, RobotDriver, RobotDriverError
from nodes.scanner.scan_control import ScanControl
from nodes.scanner.scan_plan import check_path, path_segments, plan_raster
from nodes.scanner.scan_progress import PathProgressMeter
from nodes.scanner.scan_supervision import SUPERVISION_MAX_S, ScanSupervision, supervision_period_s
from nodes.scanner.specimen import SpecimenPlanner
from nodes.scanner.surface_follow import LineFollower

# SUPERVISION_MAX_S and supervision_period_s: importable from here as before the split (nodes.scanner.scan_supervision)
__all__ = ["SUPERVISION_MAX_S", "RobotScanner", "supervision_period_s"]

_STOPPING_FAULTS = {"device_lost", "over_pressure", "tracking_error"}


class RobotScanner(palpa.Node):
    """Raster scan with a safety envelope."""

    class Params(palpa.Params):
        driver: Literal["sim", "ur_rtde"] = "sim"
        mode: Literal["sweep", "indent"] = "sweep"
        region_mm: list[float] = []
        """x0, y0, x1, y1 of the raster in the phantom frame; empty: the geometry's footprint less edge_margin_mm."""
        geometry: str = ""
        """Measured-geometry file (models.geometry): the specimen's footprint and thickness as someone measured them."""
        edge_margin_mm: float = 4.0
        """Default region: the footprint (or the searched extent) less this on every side."""
        search_box_mm: list[float] = []
        """xmin, ymin, zmin, xmax, ymax, zmax: without region_mm, find the specimen in this box: touch down from its
        top towards its floor at a grid of points search_step_mm apart (contact or none, by the touchoff signal);
        the region is the extent of the points that found it less edge_margin_mm, its surface fitted through them."""
        search_step_mm: palpa.Positive = 10.0
        touchoff: Literal["off", "heights", "indenters", "force"] = "off"
        """Find the surface before the raster (nodes/scanner/touchoff.py) by this contact signal; off: flat contact_z_mm."""
        touch_grid: int = 3
        """Touch-off points: a grid x grid lattice over the region (2: corners and centre)."""
        touch_inset_mm: float = 0.0
        """Touch-off points this far inside the region (the air-float probe's SPS ring must lie on the specimen)."""
        touch_threshold: float = 0.0
        """Contact threshold (heights, indenters: mm; force: N); 0: the signal's default (9 mm, 0.3 mm, 0.5 N)."""
        search_speed_mm_s: float = 5.0
        search_clearance_mm: float = 8.0
        """Touch-off descents start this far above the thickest measured point (the box's top without geometry)."""
        working_offset_mm: float = 1.0
        """After a touch-off, sweep: the probe face's height above the found surface."""
        follow_gain_per_s: palpa.NonNegative = 10.0
        """Sweep over a found surface with the air-float probe: its heights hold the face's clearance (eq. 2's d_n)
        at working_offset_mm along each line, taking this fraction of the error out per second (0: no following;
        nodes/scanner/surface_follow.py)."""
        follow_step_mm: palpa.Positive = 1.5
        """Following: the lines' waypoints at most this far apart (a correction acts within one step)."""
        follow_max_offset_mm: palpa.SafetyLimit[palpa.Positive] = 2.0
        """Following never moves a line more than this from its plan."""
        max_press_fraction: palpa.SafetyLimit[float] = 0.6
        """After a touch-off, indent: never press deeper than this fraction of the thinnest found point."""
        spacing_mm: palpa.Positive = 2.0
        speed_mm_s: palpa.Positive = 10.0
        """Sweep: speed along a line. Indent: press and lift speed."""
        axis: Literal["x", "y"] = "y"
        """Lines run parallel to this axis (the paper's Fig. 12 scan: y)."""
        contact_z_mm: float = 5.0
        """Probe face height while sweeping (sweep), or the surface height pressed from (indent)."""
        indent_depth_mm: palpa.Positive = 3.0
        hold_s: palpa.NonNegative = 0.5
        point_spacing_mm: palpa.NonNegative = 0.0
        """Indent mode: spacing of points along a line (0: same as spacing_mm)."""
        approach_clearance_mm: palpa.NonNegative = 5.0
        retract_clearance_mm: palpa.NonNegative = 15.0
        transit_speed_mm_s: palpa.Positive = 40.0
        approach_speed_mm_s: palpa.Positive = 10.0
        accel_mm_s2: palpa.Positive = 500.0
        home_mm: tuple[float, float, float] = (0.0, 0.0, 40.0)
        """Start pose of the simulated arm (phantom frame)."""
        workspace_mm: palpa.SafetyLimit[tuple[float, float, float, float, float, float]] = (
            -10.0, -10.0, 0.5, 70.0, 70.0, 60.0)
        """xmin, ymin, zmin, xmax, ymax, zmax: the arm never leaves this box."""
        max_speed_mm_s: palpa.SafetyLimit[palpa.Positive] = 50.0
        max_accel_mm_s2: palpa.SafetyLimit[palpa.Positive] = 1000.0
        watch_topic: palpa.SafetyLimit[Literal["probe/heights", "camera/indenters", ""]] = "probe/heights"
        """Probe data that must stay fresh while moving ('' disables the watchdog: bench tests only)."""
        watchdog_s: palpa.SafetyLimit[palpa.Positive] = 0.05
        pressure_watchdog_s: palpa.SafetyLimit[palpa.NonNegative] = 0.5
        """Once ``pressure/state`` has been heard, it going quiet this long while moving stops the arm like stale
        probe data (a dead pressure controller means unknown contact force); 0 disables."""
        stale_hold_s: palpa.SafetyLimit[palpa.NonNegative] = 0.0
        """A scan stopped by stale data (either watchdog above) holds, paused, this long for the data to come back,
        then goes on along its line from where it stopped (each hold logged and counted in the final status); still
        stale after it, the scan ends as a fault. 0: it ends at once (a probe fails instead, for its caller to
        retry, whatever this is)."""
        startup_timeout_s: palpa.Positive = 10.0
        """How long to wait for the probe's first data before giving up."""
        pose_rate_hz: palpa.Positive = 250.0
        linger_s: palpa.NonNegative = 0.5
        """After the scan: keep publishing this long so the last samples reach the map, then exit."""
        # drivers
        time_scale: palpa.Positive = 1.0
        """Sim driver: simulated seconds per clock second (use the graph's sim clock instead when you can)."""
        robot_host: str = "127.0.0.1"
        frame_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
        """Phantom frame origin in the robot base frame (mm)."""
        tool_rotvec: tuple[float, float, float] = (0.0, math.pi, 0.0)
        """Fixed tool orientation (rotation vector, rad): probe pointing down."""
        rtde_watchdog_hz: palpa.SafetyLimit[palpa.NonNegative] = 2.0
        """ur_rtde: the controller stops the program (and the arm) when this process has not kicked its RTDE
        watchdog for 1/rtde_watchdog_hz s (a stalled PC or a cut cable); 0: no watchdog."""
        autostart: bool = True
        """Run the raster at start-up (and exit when it is done); false: stay idle and serve probe_at requests."""

    params: Params

    def setup(self) -> None:
        p = self.params
        self.pose_pub = self.publisher("robot/pose", RobotPose)
        self.plan_pub = self.publisher("robot/plan", ScanPlan, latched=True)
        self.status_pub = self.publisher("robot/scan_status", ScanStatus, latched=True)
        self.state: ScanState = "planning"
        self.message = ""
        self.line = 0
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
        self.specimen = SpecimenPlanner(self)  # refuses a specimen that does not fit, before any motion
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
            self.set_state("waiting", f"waiting for probe data on {p.watch_topic}" if p.watch_topic else "")
        else:
            self.set_state("idle", "waiting for scanner/probe_at requests")
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
        from nodes.drivers.robot_urrtde import URRtdeDriver

        # the poses it reads are stamped by the node's clock, like the sim arm's (the probe's samples are matched to
        # them by stamp: a graph on another clock than the wall's, e.g. a test harness's, must not see a gap)
        return URRtdeDriver(p.robot_host, frame_offset_mm=tuple(p.frame_offset_mm),
                            tool_rotvec=tuple(p.tool_rotvec), watchdog_hz=p.rtde_watchdog_hz or None,
                            clock=self.clock.now_ns)

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

    # -- inputs ----------------------------------------------------------------------------------
    def on_probe(self, msg: ProbeHeights | IndenterDisplacements) -> None:
        self.last_probe_ns = self.clock.now_ns()
        if self.state == "touching":
            self.specimen.on_probe(msg)
        elif self.follower is not None and self.state == "scanning" and isinstance(msg, ProbeHeights):
            self.follower.on_heights(msg.stamp_ns, msg.h_mm, msg.valid)

    def on_pressure(self, msg: PressureState) -> None:
        self.last_pressure_ns = self.clock.now_ns()
        bad = _STOPPING_FAULTS.intersection(msg.faults)
        if bad and self.state in ("waiting", "touching", "scanning", "probing", "paused"):
            self.halt("fault", f"pressure fault {', '.join(sorted(bad))}")

    def on_estop(self, msg: EStop) -> None:
        if msg.engaged and self.state not in ("done", "estop"):
            self.halt("estop", f"e-stop: {msg.reason or 'engaged'}")

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

    def halt(self, state: ScanState, why: str) -> None:
        """Stop the arm now and end the scan as ``state`` (fault, estop, stopped)."""
        self.control.stale_since = None  # a scan held for stale data ends too: fresh data must not resume it
        try:
            self.driver.stop(self.params.max_accel_mm_s2)
        finally:
            self.control.fail_probe(f"the scanner stopped: {why}")
            self.log.error("STOP (%s): %s", state, why)
            self.set_state(state, why)
            self.finish(1 if state == "fault" else 2)

    def set_state(self, state: ScanState, message: str = "") -> None:
        self.state, self.message = state, message
        self.publish_status()

    def finish(self, code: int) -> None:
        self.timer(self.params.linger_s, lambda: self.request_shutdown(code), oneshot=True)

    def run_path(self, plan: RasterPlan, state: ScanState) -> None:
        """Drive ``plan`` (already checked) from where the arm is, in ``state`` (scanning, probing)."""
        self.path = plan.waypoints
        self.segments = path_segments(plan.waypoints, self.follower is not None and state == "scanning")
        self.segment = 0
        self.hold_until_ns = None
        self.meter = PathProgressMeter(plan.waypoints, plan.duration_s)
        self.set_state(state)
        self.start_segment()

    def pause(self, why: str = "") -> None:
        """Stop the arm where it is; :meth:`resume` goes on towards the waypoint it was heading for."""
        self.driver.stop(self.params.max_accel_mm_s2)
        self.resume_index = self.driver.progress().index
        self.set_state("paused", why or f"paused during {self.control.paused_from}")

    def resume(self, state: ScanState) -> None:
        self.control.stale_since = None
        a, b = self.segments[self.segment]
        a = min(a + self.resume_index, b)
        self.segments[self.segment] = (a, b)
        self.hold_until_ns = None
        self.set_state(state)
        self._send(a, b)

    def start_segment(self) -> None:
        if self.segment >= len(self.segments) and self.state == "probing":
            self.meter.complete()
            self.control.path_done()
            return
        if self.segment >= len(self.segments):
            self.meter.complete()
            holds = self.control.stale_holds
            held = f" (held {holds} time(s) for stale data)" if holds else ""
            self.set_state("done", f"scan complete in {(self.clock.now_ns() - self.started_ns) / 1e9:.1f} s{held}")
            if self.follower is not None:
                self.log.info("surface following: %d corrections, the largest %+.2f mm", self.follower.resends,
                              self.follower.largest_mm)
            self.log.info("scan complete")
            self.finish(0)
            return
        a, b = self.segments[self.segment]
        if self.follower is not None and self.state == "scanning":
            self.follower.start_line(self.path[a : b + 1], self.path[b].line, self.specimen.plan_z())
        self._send(a, b)

    def _send(self, a: int, b: int) -> None:
        """Drive path[a..b] (the current line's heights at the follower's offset while scanning)."""
        pts = self.path[a : b + 1]
        if self.follower is not None and self.state == "scanning":
            pts = self.follower.shifted(pts)
        try:
            self.driver.move_path(pts)
        except (ValueError, RobotDriverError) as exc:
            if self.state != "probing":
                raise
            self.control.driver_refused(exc)

    def resend(self, follower: LineFollower, i: int, b: int, now: int) -> None:
        """Surface following: the rest of the line (from the waypoint being approached) again, at the new offset,
        after the same checks as the plan (box, caps)."""
        try:
            self.check_path(follower.shifted(self.path[i : b + 1]))
        except palpa.ParamError as exc:
            self.halt("fault", f"surface following: {exc}")
            return
        self.segments[self.segment] = (i, b)
        self._send(i, b)
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
        if self.state not in ("done",):
            self.driver.stop(self.params.max_accel_mm_s2)  # the driver is closed after this (closing() in setup)


if __name__ == "__main__":
    palpa.run_node(RobotScanner)
