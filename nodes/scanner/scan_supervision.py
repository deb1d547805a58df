"""The robot scanner's supervision pass: what it checks every few milliseconds while the arm may move.

Waiting, it starts the touch-off, the scan or the idle wait for probes once the probe's data flows (or gives up
after ``startup_timeout_s``). Moving (a scan, a probe, a touch-off), it stops the arm on stale data (a probe fails,
a scan holds or ends as a fault: ``RobotScanner.stale_data``), on a TCP outside the workspace box and on a robot
fault; it then lets the scanner advance along its path (``follow_path``). A scan held for stale data goes on once
the data is fresh, or ends as a fault. At a touch-off's end it plans the raster over the found surface and checks
it again before it runs. It gets what it uses of the scanner as :class:`SupervisedScanner` (the node,
nodes/scanner/robot_scanner.py, owns the state this reads and the actions it takes) and changes the scanner's state
only through them (nodes.scanner.states).
"""

from __future__ import annotations

from typing import Protocol

import palpa
from models.raster import RasterPlan
from nodes.drivers.robot import MotionStatus, PathProgress
from nodes.scanner.scan_control import ScanControl, ScannerCore
from nodes.scanner.states import Event, State

__all__ = ["SUPERVISION_MAX_S", "ScanSupervision", "SupervisedScanner", "supervision_period_s"]

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


class SupervisedScanner(ScannerCore, Protocol):
    """What the supervision pass uses of the scanner (nodes.scanner.robot_scanner.RobotScanner)."""

    @property
    def control(self) -> ScanControl: ...
    @property
    def started_ns(self) -> int: ...
    @property
    def on_path(self) -> bool: ...

    def start_segment(self) -> None: ...
    def follow_path(self, prog: PathProgress, tcp: tuple[float, float, float], now: int) -> None: ...
    def make_plan(self) -> RasterPlan: ...
    def scan(self, plan: RasterPlan) -> None: ...
    def publish_table(self) -> None: ...


class ScanSupervision:
    """The scanner's periodic pass (its timer calls :meth:`supervise`), and the scan's holds for stale data."""

    def __init__(self, node: SupervisedScanner) -> None:
        self.node = node
        self.held_since = 0
        """When the scan was last held for stale data (read while it is held: State.SCAN_HELD)."""
        self.holds = 0
        """How many times the scan was held for stale data."""

    def supervise(self) -> None:
        node = self.node
        now = node.clock.now_ns()
        p = node.params
        node.control.supervise(now)
        if node.status is State.WAITING:
            flowing = node.last_probe_ns is not None or not p.watch_topic
            if flowing and node.specimen.touch is not None:
                node.change(Event.TOUCH_OFF, "finding the specimen's surface")
                node.specimen.touch.start()
            elif flowing and not p.autostart:
                node.change(Event.SERVE, "waiting for scanner/probe_at requests")
            elif flowing:
                node.change(Event.SCAN)
                node.start_segment()
            elif (now - node.started_ns) / 1e9 > p.startup_timeout_s:
                node.halt(Event.FAULT, f"no probe data on {p.watch_topic} within {p.startup_timeout_s:g} s")
            return
        if node.status is State.SCAN_HELD:
            self.supervise_hold(now)
            return
        touching = node.status is State.TOUCHING  # the touch-off moves the arm: the same checks as a scan
        if not touching and not node.on_path:
            return
        stale = node.stale_data(now)
        if stale and node.status is State.PROBING:
            node.control.stop_probe(f"the scanner stopped the arm: {stale}", f"probe stopped: {stale}")
            return
        if stale and node.status is State.SCANNING and p.stale_hold_s > 0:
            self.hold(stale, now)
            return
        if stale:
            node.halt(Event.FAULT, stale)
            return
        box = p.workspace_mm
        tcp = node.driver.state().pose[:3]  # read once a pass: on ur_rtde a state is several RTDE getters
        x, y, z = tcp
        if not (box[0] - 0.5 <= x <= box[3] + 0.5 and box[1] - 0.5 <= y <= box[4] + 0.5 and
                box[2] - 0.5 <= z <= box[5] + 0.5):
            node.halt(Event.FAULT, f"TCP at ({x:.1f}, {y:.1f}, {z:.1f}) mm is outside the workspace box")
            return
        prog = node.driver.progress()
        if prog.status in (MotionStatus.PROTECTIVE_STOP, MotionStatus.DISCONNECTED, MotionStatus.FAULT):
            node.halt(Event.FAULT, f"robot {prog.status.name.lower()}: {prog.message}")
            return
        if touching:
            self.supervise_touch()
            return
        node.follow_path(prog, tcp, now)

    # -- a scan held for stale data -------------------------------------------------------------
    def hold(self, stale: str, now_ns: int) -> None:
        """Stale data while scanning, with ``stale_hold_s`` set: stop the arm and hold the scan, paused."""
        node = self.node
        node.pause(Event.HOLD, f"held: {stale}")
        self.held_since, self.holds = now_ns, self.holds + 1
        node.log.error("HOLD: %s; the scan goes on once it is fresh again (at most %g s)", stale,
                       node.params.stale_hold_s)

    def supervise_hold(self, now_ns: int) -> None:
        """A scan held for stale data: on when the data is fresh again, a fault when it stays away too long."""
        node, since = self.node, self.held_since
        stale = node.stale_data(now_ns)
        if not stale:
            node.log.warning("the data is fresh again after %.2f s: the scan goes on", (now_ns - since) / 1e9)
            node.resume()
        elif (now_ns - since) / 1e9 > node.params.stale_hold_s:
            node.halt(Event.FAULT, f"{stale}, and not fresh again within the {node.params.stale_hold_s:g} s hold")

    # -- the touch-off ---------------------------------------------------------------------------
    def supervise_touch(self) -> None:
        """Touch-off in progress (after the scan's own checks); at its end, the raster over the found surface
        (checked against the box and caps again) or a fault."""
        node = self.node
        touch = node.specimen.touch
        if touch is None:
            return
        touch.step()
        if touch.failed:
            node.halt(Event.FAULT, touch.error)
        elif touch.done:
            if not node.params.autostart:
                try:
                    node.log.info("%s", node.specimen.finish_touch())
                except ValueError as exc:
                    node.halt(Event.FAULT, f"no surface from the touch-off: {exc}")
                    return
                node.publish_table()
                node.change(Event.SERVE, "surface found: waiting for scanner/probe_at requests")
                return
            try:
                node.log.info("%s", node.specimen.finish_touch())
                node.publish_table()
                plan = node.make_plan()
                node.check_path(plan.waypoints)
            except (ValueError, palpa.ParamError) as exc:
                node.halt(Event.FAULT, f"no raster over the found surface: {exc}")
                return
            node.scan(plan)
