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
``scanner/abort`` stops for good: a scan (its touch-off too) ends as ``stopped`` (the node exits 2), a probe is
answered with a refusal and the scanner waits for the next request. Stale data stops a probe the same way (the refusal says which
data), and the next probe is refused until it is fresh again; a path the arm's driver refuses fails the probe with
the driver's reason, the scanner idle again; a probe after a stopped one lifts the arm straight up
before its path (:func:`lift_first`), so that a probe stopped in the tissue is not dragged across it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import statistics
from collections.abc import Sequence
from typing import Any, Protocol

import palpa
from messages import ProbeAt, ProbeResult, StiffnessSample, Trigger, TriggerResult
from models.following import is_slide
from models.raster import RasterPlan, Surface, Waypoint, indent_raster, sweep_raster
from nodes.drivers.robot import RobotDriver
from nodes.scanner.scanner_params import ScannerParams
from nodes.scanner.specimen import SpecimenPlanner
from nodes.scanner.states import FINAL, Event, State
from palpa.node.service import RequestRefused, Responder, Service

__all__ = ["ControlledScanner", "ScanControl", "ScannerCore", "lift_first", "measuring_moves", "sweep_ends"]

_LIFT_TOLERANCE_MM = 0.5
"""An arm this much below a probe's first waypoint is lifted straight up to it first (:func:`lift_first`)."""
_CATCH_UP_S = 10.0
"""After the rest: the longest an answer waits for an estimate measured at or after the path's end (an estimator that
sends nothing, dead or unplugged, gets the refusal after this)."""


class ScannerCore(Protocol):
    """What both the services and the supervision pass use of the scanner (nodes.scanner.robot_scanner)."""

    @property
    def params(self) -> ScannerParams: ...
    @property
    def clock(self) -> palpa.Clock: ...
    @property
    def log(self) -> logging.Logger: ...
    @property
    def driver(self) -> RobotDriver: ...
    @property
    def specimen(self) -> SpecimenPlanner: ...
    @property
    def last_probe_ns(self) -> int | None: ...
    @property
    def status(self) -> State: ...

    def change(self, event: Event, message: str = "") -> State: ...
    def halt(self, event: Event, why: str) -> None: ...
    def stale_data(self, now: int) -> str: ...
    def check_path(self, waypoints: tuple[Waypoint, ...]) -> None: ...
    def pause(self, event: Event, why: str = "") -> None: ...
    def resume(self) -> None: ...


class ControlledScanner(ScannerCore, Protocol):
    """What the scanner's services use of the scanner."""

    def can(self, event: Event) -> bool: ...
    def run_path(self, plan: RasterPlan, event: Event) -> None: ...
    def stop_arm(self) -> None: ...


class ScanControl:
    """The scanner's services' handlers (the node serves them) and the state of the probe in progress."""

    def __init__(self, node: ControlledScanner) -> None:
        self.node = node
        self.probe: Service[ProbeAt, ProbeResult] | None = None
        """The ``scanner/probe_at`` service (set by the node that serves it): its answers are deferred."""
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
        self.stopped_on_path = False
        """The last probe stopped on its path (stale data, an abort): the next one lifts the arm first."""

    # -- probe_at --------------------------------------------------------------------------------
    def on_probe_at(self, req: ProbeAt) -> Responder[ProbeResult]:
        node = self.node
        p = node.params
        last = node.last_probe_ns
        if node.status is State.WAITING and p.watch_topic and last is None:
            raise RequestRefused(f"no fresh probe data on {p.watch_topic}: is the probe's reader running?")
        if node.status in FINAL:
            raise RequestRefused(f"the scanner has ended ({node.status.wire}) and exits after linger_s: a probe would "
                                 "be cut off mid-path; probes are served by a scanner started with autostart: false")
        if not node.can(Event.PROBE) or self.probe is None:
            raise RequestRefused(f"the scanner is {node.status.wire}, not idle (abort first, or wait)")
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
        node.run_path(plan, Event.PROBE)  # a path the driver refuses is answered at once (driver_refused)
        return responder

    def _plan(self, req: ProbeAt) -> RasterPlan:
        p = self.node.params
        half = req.length_mm / 2
        ends = (req.x_mm, req.y_mm - half, req.x_mm, req.y_mm + half) if p.axis == "y" else \
            (req.x_mm - half, req.y_mm, req.x_mm + half, req.y_mm)
        spec = self.node.specimen
        surface = spec.surface if req.mode == p.mode else None
        if req.mode == "sweep":
            ends = sweep_ends(ends, self.node.driver.state().pose[:2], surface, p.sweep_climb_mm)
        common: dict[str, Any] = dict(spacing_mm=p.spacing_mm, axis=p.axis, accel_mm_s2=p.accel_mm_s2,
                      approach_clearance_mm=p.approach_clearance_mm, retract_clearance_mm=p.retract_clearance_mm,
                      transit_speed_mm_s=p.transit_speed_mm_s)
        # over the surface the touch-off found (when one ran), as the scan's own lines would be (SpecimenPlanner.
        # plan_heights: a sweep at the working offset above it, a press from it); flat contact_z_mm otherwise
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
        self.settle_until_ns = self.path_end_ns + int(self.node.params.probe_rest_s * 1e9)
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
        node.change(Event.COMPLETE, "probe done")
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
                                    duration_s=(node.clock.now_ns() - self.started_ns) / 1e9,
                                    measured_from_ns=opened or 0, measured_to_ns=closed or 0))

    def stop_probe(self, why: str, status: str = "", event: Event = Event.PROBE_FAILED) -> None:
        """Stop the arm where it is and fail the probe in progress with ``why`` (``event``: PROBE_FAILED, or ABORT
        when asked for); the scanner stays up, idle, for the next request (a call fails, not its server: the caller
        decides). The next probe lifts the arm straight up first (:func:`lift_first`), and is refused while the
        data stays stale."""
        node = self.node
        try:
            node.stop_arm()
        finally:
            self.fail_probe(why)
            self.stopped_on_path = True
            log = node.log.info if event is Event.ABORT else node.log.error  # stale data is a fault
            log("STOP (the probe failed; the scanner waits for the next): %s", why)
            node.change(event, status or f"probe stopped: {why}")

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

    # -- pause, resume, abort --------------------------------------------------------------------
    def on_pause(self, req: Trigger) -> TriggerResult:
        node = self.node
        if not node.can(Event.PAUSE) or self.settle_until_ns is not None:
            raise RequestRefused(f"nothing to pause: the scanner is {node.status.wire}"
                                 + (" (the arm is back up, the result is coming)" if self.settle_until_ns else ""))
        was = node.status.wire
        node.pause(Event.PAUSE)
        return TriggerResult(message=f"paused ({was})", state=node.status.wire)

    def on_resume(self, req: Trigger) -> TriggerResult:
        node = self.node
        if not node.can(Event.RESUME):
            raise RequestRefused(f"nothing to resume: the scanner is {node.status.wire}")
        if stale := node.stale_data(node.clock.now_ns()):
            raise RequestRefused(f"not resuming on stale data: {stale}")
        node.resume()
        return TriggerResult(message=f"resumed ({node.status.wire})", state=node.status.wire)

    def on_abort(self, req: Trigger) -> TriggerResult:
        node = self.node
        status = node.status
        if not node.can(Event.ABORT):
            raise RequestRefused(f"nothing to abort: the scanner is {status.wire}")
        if status in (State.PROBING, State.PROBE_PAUSED):
            what = "probing"
            self.stop_probe("aborted by scanner/abort", "probe aborted", Event.ABORT)
        else:
            what = "scanning" if status in (State.SCAN_PAUSED, State.SCAN_HELD) else status.wire
            node.halt(Event.ABORT, "scan aborted by scanner/abort")
        return TriggerResult(message=f"aborted ({what})", state=node.status.wire)


def sweep_ends(ends: tuple[float, float, float, float], here: Sequence[float], surface: Surface | None,
               climb_mm: float) -> tuple[float, float, float, float]:
    """A probe's sweep line ``ends`` (x0, y0, x1, y1) in the order it is swept: up the ``surface`` when the line
    rises by more than ``climb_mm`` (the air-float indenter's bore friction reads a thinning layer softer than a
    thickening one: ScannerParams.sweep_climb_mm), else from the end nearer the arm at ``here`` (x, y), so that a
    planner going down a column of short sweeps does not travel past each line to come back up it."""
    a, b = ends[:2], ends[2:]
    if surface is not None:
        rise = surface(*b) - surface(*a)
        if abs(rise) > climb_mm:
            return ends if rise > 0 else (*b, *a)
    return (*b, *a) if math.dist(here, b) < math.dist(here, a) else ends


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
