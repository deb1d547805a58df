"""The robot scanner's services: probe one point, pause, resume and abort (palpa.node.service).

``scanner/probe_at`` (:class:`ProbeAt` -> :class:`ProbeResult`) drives a short path at the point (a sweep line or
an indentation, checked against the same workspace box and caps as a scan), collects the estimator's valid
``stiffness/sample`` estimates within a radius of the point measured while the probe was on the path's measuring
part (sliding along the line at the working height, or pressing and holding: not the transit, the descent onto
the line nor the retract, where the air-float probe's floating indenter still reaches the tissue and reads it
from up to ~9 mm higher, at other loads), and answers with their median a rest after the path's end, once the
estimator has caught up with the path (an estimate measured at or after its end has arrived: on a busy machine the
estimates of a wall-clock rig come late, and an answer made without them would be a refusal or the median of the
path's first part). The reply is deferred: the scanner keeps running (watchdog, pose, status) meanwhile, and
progress shows on ``robot/scan_status`` (state ``probing``) like a scan's.
``scanner/pause`` stops the arm where it is, ``scanner/resume`` goes on from the waypoint it was heading for,
``scanner/abort`` stops for good: a scan ends as ``stopped`` (the node exits 2), a probe is answered with a
refusal and the scanner waits for the next request. Stale data stops a probe the same way (the refusal says which
data), and the next probe is refused until it is fresh again; a path the arm's driver refuses fails the probe with
the driver's reason, the scanner idle again; a probe after a stopped one lifts the arm straight up
before its path (:func:`lift_first`), so that a probe stopped in the tissue is not dragged across it.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import palpa
from messages import ProbeAt, ProbeResult, StiffnessSample, Trigger, TriggerResult
from messages.robot import ScanState
from models.following import is_slide
from models.raster import RasterPlan, Waypoint, indent_raster, sweep_raster
from palpa.node.service import RequestRefused, Responder

if TYPE_CHECKING:
    from nodes.scanner.robot_scanner import RobotScanner

__all__ = ["MOVING", "ScanControl", "lift_first", "measuring_moves"]

MOVING = ("scanning", "probing")
_SETTLE_S = 0.6
"""After a probe's path: the rest at its end, and time for the estimator to publish the last estimates (its
max_wait_s is 0.25 s); the earliest answer."""
_LIFT_TOLERANCE_MM = 0.5
"""An arm this much below a probe's first waypoint is lifted straight up to it first (:func:`lift_first`)."""
_CATCH_UP_S = 10.0
"""After the rest: the longest an answer waits for an estimate measured at or after the path's end (an estimator that
sends nothing, dead or unplugged, gets the refusal after this)."""


class ScanControl:
    """Serves the scanner's services and keeps the state of the probe in progress."""

    def __init__(self, node: RobotScanner) -> None:
        self.node = node
        self.request: ProbeAt | None = None
        self.responder: Responder[ProbeResult] | None = None
        self.values: list[tuple[int, float]] = []  # (measured at, value) of the valid estimates near the point
        self.unit = ""
        self.measuring: list[int] = []  # the path's measuring moves (the waypoints they end at)
        self.opened_ns: int | None = None  # when the probe was first seen on a measuring move
        self.closed_ns: int | None = None  # ... and first seen past the last one (or the path ended)
        self.started_ns = 0
        self.settle_until_ns: int | None = None
        self.path_end_ns = 0
        self.latest_ns: int | None = None
        """The latest measurement stamp of any estimate (valid or not, anywhere) heard during the probe."""
        self.paused_from: ScanState = "scanning"  # set by on_pause before anything reads it
        self.stopped_on_path = False
        """The last probe stopped on its path (stale data, an abort): the next one lifts the arm first."""
        self.stale_since: int | None = None
        """The scan held for stale data since then (the scanner's stale_hold_s)."""
        self.stale_holds = 0
        self.probe = node.service("scanner/probe_at", ProbeAt, ProbeResult, self.on_probe_at)
        node.service("scanner/pause", Trigger, TriggerResult, self.on_pause)
        node.service("scanner/resume", Trigger, TriggerResult, self.on_resume)
        node.service("scanner/abort", Trigger, TriggerResult, self.on_abort)
        node.subscribe("stiffness/sample", StiffnessSample, self.on_sample)

    # -- probe_at --------------------------------------------------------------------------------
    def on_probe_at(self, req: ProbeAt) -> Responder[ProbeResult]:
        node = self.node
        p = node.params
        last = node.last_probe_ns
        if node.state == "waiting" and p.watch_topic and last is None:
            raise RequestRefused(f"no fresh probe data on {p.watch_topic}: is the probe's reader running?")
        if node.state not in ("idle", "done"):
            raise RequestRefused(f"the scanner is {node.state}, not idle (abort first, or wait)")
        if p.watch_topic and last is None:
            raise RequestRefused(f"no fresh probe data on {p.watch_topic}: is the probe's reader running?")
        if stale := node.stale_data(node.clock.now_ns()):
            raise RequestRefused(f"no fresh data to move on: {stale}")
        if not (req.length_mm > 0 and req.radius_mm > 0):
            raise palpa.ParamError(f"length_mm and radius_mm must be > 0, got {req.length_mm}, {req.radius_mm}")
        try:
            plan = self._plan(req)
            if self.stopped_on_path:
                plan = lift_first(plan, node.driver.state().pose[:3])
            node.check_path(plan.waypoints)
        except (ValueError, palpa.ParamError) as exc:
            raise RequestRefused(f"cannot probe at ({req.x_mm:g}, {req.y_mm:g}) mm: {exc}") from None
        self.request, self.values, self.started_ns, self.latest_ns = req, [], node.clock.now_ns(), None
        self.measuring, self.opened_ns, self.closed_ns = measuring_moves(plan.waypoints), None, None
        responder = self.responder = self.probe.defer()
        self.stopped_on_path = False
        node.log.info("probing (%.1f, %.1f) mm: %s, %d waypoints", req.x_mm, req.y_mm, req.mode,
                      len(plan.waypoints))
        node.run_path(plan, "probing")  # a path the driver refuses is answered at once (driver_refused)
        return responder

    def _plan(self, req: ProbeAt) -> RasterPlan:
        p = self.node.params
        half = req.length_mm / 2
        ends = (req.x_mm, req.y_mm - half, req.x_mm, req.y_mm + half) if p.axis == "y" else \
            (req.x_mm - half, req.y_mm, req.x_mm + half, req.y_mm)
        common: dict[str, Any] = dict(spacing_mm=p.spacing_mm, axis=p.axis, accel_mm_s2=p.accel_mm_s2,
                      approach_clearance_mm=p.approach_clearance_mm, retract_clearance_mm=p.retract_clearance_mm,
                      transit_speed_mm_s=p.transit_speed_mm_s)
        # over the surface the touch-off found (when one ran), as the scan's own lines would be (SpecimenPlanner.
        # plan_heights: a sweep at the working offset above it, a press from it); flat contact_z_mm otherwise
        spec = self.node.specimen
        surface = spec.surface if req.mode == p.mode else None
        if req.mode == "sweep":
            return sweep_raster(*ends, contact_z_mm=p.working_offset_mm if surface else p.contact_z_mm,
                                surface=surface, speed_mm_s=p.speed_mm_s, approach_speed_mm_s=p.approach_speed_mm_s,
                                **common)
        return indent_raster(req.x_mm, req.y_mm, req.x_mm, req.y_mm, contact_z_mm=0.0 if surface else p.contact_z_mm,
                             surface=surface, depth_mm=spec.press_depth_mm(), hold_s=p.hold_s,
                             press_speed_mm_s=p.speed_mm_s, **common)

    def on_sample(self, s: StiffnessSample) -> None:
        req = self.request
        if req is None:
            return
        self.latest_ns = s.stamp_ns if self.latest_ns is None else max(self.latest_ns, s.stamp_ns)
        if not s.valid or math.dist((s.x_mm, s.y_mm), (req.x_mm, req.y_mm)) > req.radius_mm:
            return
        self.values.append((s.stamp_ns, s.value))
        self.unit = s.unit

    def path_done(self) -> None:
        """The probe's path is complete: answer after the rest, once the estimator has caught up (module doc)."""
        self.path_end_ns = self.node.clock.now_ns()
        self.settle_until_ns = self.path_end_ns + int(_SETTLE_S * 1e9)
        if self.closed_ns is None:
            self.closed_ns = self.path_end_ns

    def track(self, index: int, now_ns: int) -> None:
        """The scanner's supervision saw the arm heading for waypoint ``index`` of the path: open the measuring
        window when it is first on a measuring move, close it once past them."""
        if self.request is None or self.closed_ns is not None or not self.measuring:
            return
        if self.opened_ns is None and index >= self.measuring[0]:
            self.opened_ns = now_ns
        if index > self.measuring[-1]:
            self.closed_ns = now_ns

    def supervise(self, now_ns: int) -> None:
        until = self.settle_until_ns
        if until is None or now_ns < until:
            return
        caught_up = self.latest_ns is not None and self.latest_ns >= self.path_end_ns
        if caught_up or now_ns >= until + int(_CATCH_UP_S * 1e9):
            self.settle_until_ns = None
            self._answer()

    def _answer(self) -> None:
        node, req, responder = self.node, self.request, self.responder
        self.request = self.responder = None
        node.set_state("idle", "probe done")
        if req is None or responder is None:
            return
        opened, closed = self.opened_ns, self.closed_ns
        values = [v for t, v in self.values if opened is not None and closed is not None and opened <= t <= closed]
        if not values:
            latest = self.latest_ns
            heard = ("no estimate at all came: is the estimator running?" if latest is None else
                     f"the estimator lags: its latest estimate was measured {(self.path_end_ns - latest) / 1e9:.1f} s "
                     "before the path's end" if latest < self.path_end_ns else
                     f"{len(self.values)} were, but none on the path's measuring part" if self.values else
                     "none of its estimates was")
            responder.refuse(f"no valid stiffness estimate within {req.radius_mm:g} mm of ({req.x_mm:g}, "
                             f"{req.y_mm:g}) mm ({heard}; probe data on {node.params.watch_topic or 'no topic'}?)")
            return
        median = statistics.median(values)
        mad = statistics.median(abs(v - median) for v in values)
        node.log.info("probe at (%.1f, %.1f) mm: %.2f %s from %d estimates (%d near it in transit left out)",
                      req.x_mm, req.y_mm, median, self.unit, len(values), len(self.values) - len(values))
        responder.reply(ProbeResult(x_mm=req.x_mm, y_mm=req.y_mm, value=median, unit=self.unit,
                                    samples=len(values), mad=mad,
                                    duration_s=(node.clock.now_ns() - self.started_ns) / 1e9))

    def stop_probe(self, why: str, status: str = "", *, asked: bool = False) -> None:
        """Stop the arm where it is and fail the probe in progress with ``why``; the scanner stays up, idle, for
        the next request (a call fails, not its server: the caller decides). The next probe lifts the arm straight
        up first (:func:`lift_first`), and is refused while the data stays stale."""
        node = self.node
        try:
            node.driver.stop(node.params.max_accel_mm_s2)
        finally:
            self.fail_probe(why)
            self.stopped_on_path = True
            log = node.log.info if asked else node.log.error  # an abort is asked for, stale data is a fault
            log("STOP (the probe failed; the scanner waits for the next): %s", why)
            node.set_state("idle", status or f"probe stopped: {why}")

    def driver_refused(self, exc: Exception) -> None:
        """The arm's driver refused a path of the probe (a protective stop, a path it cannot drive): the probe fails
        with the driver's reason and the scanner is idle for the next request (not left ``probing``)."""
        why = f"the arm's driver refused the probe's path: {exc}"
        self.stop_probe(why, f"probe refused: {why}")

    def fail_probe(self, why: str) -> None:
        """End the probe in progress (if any) without a result."""
        responder, self.responder, self.request, self.settle_until_ns = self.responder, None, None, None
        if responder is not None:
            responder.refuse(why)

    # -- a scan held for stale data -------------------------------------------------------------
    def hold(self, stale: str, now_ns: int) -> None:
        """Stale data while scanning, with ``stale_hold_s`` set: stop the arm and hold the scan, paused."""
        node = self.node
        self.paused_from = "scanning"
        node.pause(f"held: {stale}")
        self.stale_since, self.stale_holds = now_ns, self.stale_holds + 1
        node.log.error("HOLD: %s; the scan goes on once it is fresh again (at most %g s)", stale,
                       node.params.stale_hold_s)

    def supervise_hold(self, now_ns: int) -> None:
        """A scan held for stale data: on when the data is fresh again, a fault when it stays away too long."""
        node, since = self.node, self.stale_since
        assert since is not None
        stale = node.stale_data(now_ns)
        if not stale:
            node.log.warning("the data is fresh again after %.2f s: the scan goes on", (now_ns - since) / 1e9)
            node.resume("scanning")
        elif (now_ns - since) / 1e9 > node.params.stale_hold_s:
            node.halt("fault", f"{stale}, and not fresh again within the {node.params.stale_hold_s:g} s hold")

    # -- pause, resume, abort --------------------------------------------------------------------
    def on_pause(self, req: Trigger) -> TriggerResult:
        node = self.node
        if node.state not in MOVING or self.settle_until_ns is not None:
            raise RequestRefused(f"nothing to pause: the scanner is {node.state}"
                                 + (" (the arm is back up, the result is coming)" if self.settle_until_ns else ""))
        self.paused_from = node.state
        node.pause()
        return TriggerResult(message=f"paused ({self.paused_from})", state=node.state)

    def on_resume(self, req: Trigger) -> TriggerResult:
        node = self.node
        if node.state != "paused":
            raise RequestRefused(f"nothing to resume: the scanner is {node.state}")
        if stale := node.stale_data(node.clock.now_ns()):
            raise RequestRefused(f"not resuming on stale data: {stale}")
        node.resume(self.paused_from)
        return TriggerResult(message=f"resumed ({node.state})", state=node.state)

    def on_abort(self, req: Trigger) -> TriggerResult:
        node = self.node
        state = self.paused_from if node.state == "paused" else node.state
        if state == "probing":
            self.stop_probe("aborted by scanner/abort", "probe aborted", asked=True)
        elif state in ("scanning", "waiting"):
            node.halt("stopped", "scan aborted by scanner/abort")
        else:
            raise RequestRefused(f"nothing to abort: the scanner is {node.state}")
        return TriggerResult(message=f"aborted ({state})", state=node.state)


def lift_first(plan: RasterPlan, at: Sequence[float]) -> RasterPlan:
    """``plan`` preceded by a lift straight up from ``at`` (x, y, z mm) to the plan's first height when the arm is
    lower: after a probe stopped on its path the probe may still touch the tissue, and its move to the next one
    must not drag it across."""
    first = plan.waypoints[0]
    x, y, z = (float(v) for v in at[:3])
    if z >= first.z_mm - _LIFT_TOLERANCE_MM:
        return plan
    lift = Waypoint(x, y, first.z_mm, first.speed_mm_s, first.accel_mm_s2, 0.0, 0.0, first.line, "retract")
    return dataclasses.replace(plan, waypoints=(lift, *plan.waypoints),
                               duration_s=plan.duration_s + (first.z_mm - z) / first.speed_mm_s)


def measuring_moves(path: tuple[Waypoint, ...]) -> list[int]:
    """The waypoints that end a probe's measuring moves: the slides along a sweep line at the working height, or a
    press and its hold; sorted."""
    return [i for i, w in enumerate(path) if is_slide(path, i) or w.kind in ("press", "hold")]
