"""The robot scanner's supervision pass: what it checks every few milliseconds while the arm may move.

Waiting, it starts the touch-off, the scan or the idle wait for probes once the probe's data flows (or gives up
after ``startup_timeout_s``). Moving (a scan, a probe, a touch-off), it stops the arm on stale data (a probe fails,
a scan holds or ends as a fault: ``RobotScanner.stale_data``), on a TCP outside the workspace box and on a robot
fault; it then advances the path: progress, the probe's measuring window, the surface follower's corrections, the
holds at press points and the next segment. At a touch-off's end it plans the raster over the found surface and
checks it again before it runs. Split from nodes/scanner/robot_scanner.py, which owns the state this reads and the actions
it takes (halt, set_state, start_segment, resend).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import palpa
from nodes.drivers.robot import MotionStatus
from nodes.scanner.scan_control import MOVING

if TYPE_CHECKING:
    from nodes.scanner.robot_scanner import RobotScanner

__all__ = ["SUPERVISION_MAX_S", "ScanSupervision", "supervision_period_s"]

SUPERVISION_MAX_S = 0.01
"""The longest the scanner goes without checking its watchdogs, the workspace box and the arm's status."""


def supervision_period_s(pose_rate_hz: float) -> float:
    """How often the scanner supervises: a whole number of pose periods, as many as fit in
    :data:`SUPERVISION_MAX_S`, so that both timers fall on the same instants (a lockstep simulation pays for every
    distinct instant: at 250 Hz, 8 ms instead of 10 ms made 300 instants a simulated second, now 250). Poses
    slower than that: every :data:`SUPERVISION_MAX_S`."""
    pose_ns = int(1.0 / pose_rate_hz * 1e9)  # as palpa.Node.timer makes the pose timer's period
    k = int(SUPERVISION_MAX_S * 1e9) // pose_ns
    return (k * pose_ns + 0.5) / 1e9 if k else SUPERVISION_MAX_S


class ScanSupervision:
    """The scanner's periodic pass (its timer calls :meth:`supervise`)."""

    def __init__(self, node: RobotScanner) -> None:
        self.node = node

    def supervise(self) -> None:
        node = self.node
        now = node.clock.now_ns()
        p = node.params
        node.control.supervise(now)
        if node.state == "waiting":
            if (node.last_probe_ns is not None or not p.watch_topic) and node.specimen.touch is not None:
                node.set_state("touching", "finding the specimen's surface")
                node.specimen.touch.start()
            elif (node.last_probe_ns is not None or not p.watch_topic) and not p.autostart:
                node.set_state("idle", "waiting for scanner/probe_at requests")
            elif node.last_probe_ns is not None or not p.watch_topic:
                node.set_state("scanning")
                node.start_segment()
            elif (now - node.started_ns) / 1e9 > p.startup_timeout_s:
                node.halt("fault", f"no probe data on {p.watch_topic} within {p.startup_timeout_s:g} s")
            return
        if node.control.stale_since is not None:
            node.control.supervise_hold(now)
            return
        touching = node.state == "touching"  # the touch-off moves the arm: the same checks as a scan
        if not touching and (node.state not in MOVING or node.segment >= len(node.segments)):
            return
        stale = node.stale_data(now)
        if stale and node.state == "probing":
            node.control.stop_probe(f"the scanner stopped the arm: {stale}", f"probe stopped: {stale}")
            return
        if stale and node.state == "scanning" and p.stale_hold_s > 0:
            node.control.hold(stale, now)
            return
        if stale:
            node.halt("fault", stale)
            return
        box = p.workspace_mm
        tcp = node.driver.state().pose[:3]  # read once a pass: on ur_rtde a state is several RTDE getters
        x, y, z = tcp
        if not (box[0] - 0.5 <= x <= box[3] + 0.5 and box[1] - 0.5 <= y <= box[4] + 0.5 and
                box[2] - 0.5 <= z <= box[5] + 0.5):
            node.halt("fault", f"TCP at ({x:.1f}, {y:.1f}, {z:.1f}) mm is outside the workspace box")
            return
        prog = node.driver.progress()
        if prog.status in (MotionStatus.PROTECTIVE_STOP, MotionStatus.DISCONNECTED, MotionStatus.FAULT):
            node.halt("fault", f"robot {prog.status.name.lower()}: {prog.message}")
            return
        if touching:
            self.supervise_touch()
            return
        seg_start, seg_end = node.segments[node.segment]
        node.meter.update(seg_start + prog.index, tcp)
        if node.state == "probing":
            node.control.track(seg_start + prog.index, now)
        if node.follower is not None and node.state == "scanning" and prog.status == MotionStatus.MOVING:
            node.follower.track(node.path, seg_start + prog.index)
            if node.follower.due(now):
                node.resend(node.follower, seg_start + prog.index, seg_end, now)
                return
        if node.hold_until_ns is not None:
            if now >= node.hold_until_ns:
                node.hold_until_ns = None
                node.segment += 1
                node.start_segment()
            return
        if prog.status == MotionStatus.DONE:
            hold = node.path[seg_end].hold_s
            if hold > 0:
                node.hold_until_ns = now + int(hold * 1e9)
            else:
                node.segment += 1
                node.start_segment()
        elif prog.status == MotionStatus.STOPPED:
            node.halt("stopped", prog.message or "the arm stopped")

    def supervise_touch(self) -> None:
        """Touch-off in progress (after the scan's own checks); at its end, the raster over the found surface
        (checked against the box and caps again) or a fault."""
        node = self.node
        touch = node.specimen.touch
        if touch is None:
            return
        touch.step()
        if touch.failed:
            node.halt("fault", touch.error)
        elif touch.done:
            if not node.params.autostart:
                try:
                    node.log.info("%s", node.specimen.finish_touch())
                except ValueError as exc:
                    node.halt("fault", f"no surface from the touch-off: {exc}")
                    return
                node.set_state("idle", "surface found: waiting for scanner/probe_at requests")
                return
            try:
                node.log.info("%s", node.specimen.finish_touch())
                plan = node.make_plan()
                node.check_path(plan.waypoints)
            except (ValueError, palpa.ParamError) as exc:
                node.halt("fault", f"no raster over the found surface: {exc}")
                return
            node.plan = plan
            node.publish_plan()
            node.run_path(plan, "scanning")
