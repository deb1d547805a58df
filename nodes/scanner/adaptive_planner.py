"""Adaptive palpation planner (issue 20): probes where the map is still ambiguous, stops when it is not.

Drives the scanner through ``scanner/probe_at`` (the scanner on ``autostart: false``), one request at a time with
the non-blocking call form: the reply arrives in a callback, the node keeps running meanwhile. The scanner checks
every request against its workspace box, speed caps and watchdog; a refused request is logged, the point is
retried up to ``retries`` times (the scanner may be busy or still waiting for probe data) and then given up, and
the planner carries on with the next best point; the cells a point given up would have measured count as covered
(detect) or resolved (lse), so that tissue the probe cannot answer from holds no stop rule. Presses (``mode:
indent``) with ``tip_circle_mm`` go only where every tip of the camera probe lands on the measured footprint
(models.adaptive_edge): a tip off the specimen leaves no valid estimate.

What it learns from: every valid ``stiffness/sample`` its probes measured (nodes.scanner.probe_samples), binned
into the belief grid (the per-cell median, as the map aggregator's), so a sweep teaches it the cells it crossed,
not one number. The belief is
:func:`models.adaptive.fit_belief` (GP regression). With ``stop_rule: detect`` (default) the planner first makes
the coarse pass (models.adaptive_route: the whole covering lattice, chosen before any sweep and visited in one short
route), then the next point and the end are :func:`models.adaptive_detect.decide`'s: sample every candidate's
boundary (suspects and detections by the map detector's own false-alarm law), the nearest open point first, cover
what is left until an inclusion of the smallest size of interest is unlikely to hide, then stop; inclusions are detected on the measured cells (GP
mean only near them) against the baseline of the stiffness-blind probes. With ``stop_rule: lse`` the straddle /
ILS-UCB acquisition (:func:`models.adaptive.next_probe`) and LSE's ambiguous area (:func:`models.adaptive.should_stop`)
on the GP mean.

Publishes ``planner/mean``, ``planner/std`` and ``planner/map`` (the map inclusions are detected on; StiffnessMap,
latched) after every probe, and at the end writes the same files as a raster scan's map (``map.npz`` of that map
with the grids its detection used, ``measured`` and the stiffness-blind ``fair`` cells, and its parameters and
region, ``planner``: what nodes.scanner.planner_map detects on it again by the planner's rule; ``map.png``;
``inclusions.json``: nodes.mapping.map_output) plus ``planner.json`` (probes, refusals, simulated time, why it
stopped, and with the detect rule ``unsensed``: per reach of interest the fraction of the region where an inclusion
sensed from that far could still lie unseen; the smallest's cells are ``map.npz``'s ``unsensed`` and ``map.png``'s
grey), publishes ``map/inclusions`` and exits: it is the launch's required node. It exits 0 only when nothing was
lost: a probe given up after the scanner's refusals, or estimates lost on the way, make the run incomplete (exit 1,
``incomplete`` in planner.json, and the given-up sweeps' area counts as unsensed).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

import palpa
from messages import (
    Inclusions,
    ProbeAt,
    ProbeResult,
    ScanStatus,
    StiffnessMap,
    StiffnessSample,
)
from models.adaptive import (
    Belief,
    fit_belief,
    initial_design,
    next_probe,
    should_stop,
)
from models.adaptive_cover import seed_design
from models.adaptive_detect import (
    candidate_map,
    decide,
    detect_candidates,
    detector_config,
    swept_cells,
    unsensed,
)
from models.adaptive_edge import press_region, probe_tips
from models.adaptive_route import coarse_pass
from models.detector import Detection, detect, peak_significance
from models.geometry import GeometryError, load_geometry
from models.stiffness_map import MapSnapshot, StiffnessGrid
from models.surface import region_in_footprint
from nodes.mapping.map_output import (
    MapNotWritten,
    detection_summary,
    inclusions_message,
    write_outputs,
)
from nodes.scanner.planner_map import planner_settings
from nodes.scanner.planner_params import PlannerParams, planner_config
from nodes.scanner.probe_samples import Point, ProbeSamples
from palpa.atomic import write_beside
from palpa.node.service import ServiceError
from palpa.node.service_client import Future

__all__ = ["AdaptivePlanner"]


class AdaptivePlanner(palpa.Node):
    """Picks probe points from a GP belief of stiffness and sends them to the scanner (module doc)."""

    Params = PlannerParams
    params: PlannerParams

    def setup(self) -> None:
        p = self.params
        if p.mode not in ("sweep", "indent"):
            raise palpa.ParamError(f"{self.name}: mode must be sweep or indent, got {p.mode!r}")
        try:
            region = self._region()
            self.cfg = planner_config(p, region)
        except (ValueError, GeometryError) as exc:
            raise palpa.ParamError(f"{self.name}: {exc}") from None
        x0, y0, x1, y1 = region
        self.grid = StiffnessGrid(x0, y0, x1, y1, p.resolution_mm, min_count=p.min_count)
        self.fair = StiffnessGrid(x0, y0, x1, y1, p.resolution_mm, min_count=p.min_count)
        """The cells measured by stiffness-blind probes (seed grid, covering sweeps): the detector's baseline."""
        self.samples = ProbeSamples(mode=p.mode, length_mm=p.length_mm, radius_mm=p.radius_mm,
                                    tolerance_mm=p.resolution_mm)
        """The probe in flight and the last one made, and their samples not yet in the grids."""
        self.unit = ""
        coarse = coarse_pass(self.cfg) if self.cfg.stop_rule == "detect" and p.coarse_pass else []
        if coarse:
            self.queue = [(pt, True, "coarse pass") for pt in coarse]
        else:
            seeds = seed_design(self.cfg) if self.cfg.stop_rule == "detect" else initial_design(self.cfg)
            self.queue = [(pt, True, "seed") for pt in seeds]
        """(point, blind, why): the points to probe next; blind when chosen without looking at stiffness; why: what
        the acquisition meant it for (seed, covering, resolving a candidate, ...)."""
        self.why: list[str] = []
        """For every probe made, why it was chosen (planner.json)."""
        self.probed: list[tuple[float, float]] = []
        self.blind: list[bool] = []
        """For every probe made, whether it was stiffness-blind (its samples go to the baseline's grid)."""
        self.given_up: list[tuple[float, float]] = []
        """Points the scanner refused every time: never chosen again, not counted as probes."""
        self.tries: dict[tuple[float, float], int] = {}
        self.refused = 0
        self.inflight_why = ""
        self.retry_at_ns = 0
        self.started_ns: int | None = None
        self.belief: Belief | None = None
        self.done = False
        self.probe_at = self.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=p.call_timeout_s)
        self.mean_pub = self.publisher("planner/mean", StiffnessMap, latched=True)
        self.std_pub = self.publisher("planner/std", StiffnessMap, latched=True)
        self.map_pub = self.publisher("planner/map", StiffnessMap, latched=True)
        self.inc_pub = self.publisher("map/inclusions", Inclusions, latched=True)
        self.scanner_state = ""
        self.subscribe("stiffness/sample", StiffnessSample, self.on_sample)
        self.subscribe("robot/scan_status", ScanStatus, self.on_status)
        self.timer(0.05, self.step)

    def _region(self) -> tuple[float, float, float, float]:
        """The region the planner presses or sweeps in: ``region_mm``, else the measured footprint less
        ``edge_margin_mm``; for presses with ``tip_circle_mm``, cut to where every tip lands on the footprint
        (models.adaptive_edge: elsewhere no estimate is valid)."""
        p = self.params
        footprint = load_geometry(p.geometry).footprint_mm() if p.geometry else None
        if p.region_mm:
            if len(p.region_mm) != 4:
                raise ValueError(f"region_mm needs x0, y0, x1, y1, got {p.region_mm}")
            x0, y0, x1, y1 = (float(v) for v in p.region_mm)
            region = x0, y0, x1, y1
        elif footprint is None:
            raise ValueError("no region: give region_mm, or a geometry file with the specimen's footprint")
        else:
            region = region_in_footprint(footprint, p.edge_margin_mm)
        if p.mode != "indent" or p.tip_circle_mm <= 0:
            return region
        if footprint is None:
            self.log.warning("tip_circle_mm without a footprint (geometry): presses at the region's edge may have a "
                             "tip off the specimen and no valid estimate")
            return region
        cut = press_region(region, footprint, probe_tips(p.tip_circle_mm), p.tip_margin_mm)
        if cut != region:
            self.log.info("pressing in x %.1f..%.1f, y %.1f..%.1f mm, not x %.1f..%.1f, y %.1f..%.1f: there every tip "
                          "lands %.1f mm inside the measured footprint (models.adaptive_edge)",
                          cut[0], cut[2], cut[1], cut[3], region[0], region[2], region[1], region[3], p.tip_margin_mm)
        return cut

    def on_status(self, s: ScanStatus) -> None:
        self.scanner_state = s.state

    def on_sample(self, s: StiffnessSample) -> None:
        # only what its probes measured where they were sent, on their measuring part (nodes.scanner.probe_samples)
        if not s.valid or not self.samples.add(s):
            return
        self.unit = s.unit
        if s.model != self.cfg.model:  # the probe's own false-alarm law for every detection (models.detector)
            self.cfg = replace(self.cfg, model=s.model)

    # -- the loop ----------------------------------------------------------------------------------
    def step(self) -> None:
        """Send the next request when none is in flight and the scanner is there."""
        if self.done or self.samples.inflight is not None or self.clock.now_ns() < self.retry_at_ns:
            return
        # the scanner may first be finding the surface (touch-off): a request would only be refused
        if not self.probe_at.ready() or self.scanner_state not in ("idle", "done"):
            return
        if self.started_ns is None:
            self.started_ns = self.clock.now_ns()
        if len(self.probed) >= self.cfg.max_probes:   # the initial design too stays within the budget
            self.finish(f"probe budget spent ({len(self.probed)} probes)")
            return
        if not self.queue:
            stop, why = self._decide()
            if stop:
                self.finish(why)
                return
        (x, y), blind, self.inflight_why = self.queue.pop(0)
        self.samples.sent((x, y), blind, self.clock.now_ns())
        req = ProbeAt(x_mm=x, y_mm=y, mode=self.params.mode,
                      length_mm=self.params.length_mm, radius_mm=self.params.radius_mm)
        self.probe_at.call_async(req).add_done_callback(self.on_result)

    def on_result(self, fut: Future[ProbeResult]) -> None:
        err = fut.exception()
        if err is None:
            r = fut.result()
            point, blind = self.samples.answered((r.measured_from_ns, r.measured_to_ns))
            self.probed.append(point)
            self.blind.append(blind)
            self.why.append(self.inflight_why)
            self.log.info("probe %d at (%.1f, %.1f) mm (%s): %.2f %s from %d estimates", len(self.probed), *point,
                          self.inflight_why, r.value, r.unit, r.samples)
            self._update_belief()
            return
        self._refused(*self.samples.refused(), err)

    def _refused(self, point: Point, blind: bool, err: ServiceError) -> None:
        self.refused += 1
        n = self.tries[point] = self.tries.get(point, 0) + 1
        if n <= self.params.retries:
            self.log.warning("probe at (%.1f, %.1f) mm refused (%s): retrying", *point, err)
            self.queue.insert(0, (point, blind, self.inflight_why))
            self.retry_at_ns = self.clock.now_ns() + 500_000_000
        else:
            self.log.warning("probe at (%.1f, %.1f) mm refused %d times (%s): giving it up", *point, n, err)
            self.given_up.append(point)

    def _observations(self) -> tuple[list[tuple[float, float]], list[float]]:
        pending = self.samples.take()
        if pending:
            xs, ys, vs, blind = (np.array(v) for v in zip(*pending, strict=True))
            self.grid.add(xs, ys, vs)
            if blind.any():
                self.fair.add(xs[blind], ys[blind], vs[blind])
        snap = self.grid.snapshot()
        ok = np.isfinite(snap.stiffness)
        gx, gy = np.meshgrid(snap.x_mm, snap.y_mm)
        return list(zip(gx[ok].tolist(), gy[ok].tolist(), strict=True)), snap.stiffness[ok].tolist()

    def _update_belief(self) -> None:
        pts, vals = self._observations()
        if len(pts) < 2:
            return
        # hyper-parameters re-optimised every refit_every probes; in between only the posterior is updated
        old = self.belief
        reuse = old is not None and len(self.probed) % self.params.refit_every != 0
        self.belief = fit_belief(pts, vals, self.cfg, kernel=old.kernel if reuse and old else None)
        self._publish_belief(self._map(self.belief), final=False)

    def _decide(self) -> tuple[bool, str]:
        """Stop, or queue the acquisition's next point."""
        b = self.belief
        if len(self.given_up) >= self.cfg.max_probes:
            return True, f"{len(self.given_up)} points refused by the scanner"
        if b is None:
            return True, "no stiffness estimate from the initial probes"
        snap = self.grid.snapshot()
        if self.cfg.stop_rule == "detect":
            last = self.probed[-1] if self.probed else None
            d = decide(b, snap.stiffness, snap.count, self.probed + self.given_up, self.cfg, last,
                       self.fair.snapshot().stiffness, self.given_up)
            if not d.stop and d.point is not None:
                self.queue.append((d.point, d.blind, d.kind))
            return d.stop, d.why
        # the edge rule (as the detect rule's): the cells of a point given up count as resolved, or LSE would hold
        # its stop for tissue the probe cannot answer from and ask for the next press beside it
        observed = swept_cells(snap.count >= self.params.min_count, snap.x_mm, snap.y_mm, self.given_up, self.cfg)
        stop, why = should_stop(b, len(self.probed), self.cfg, observed)
        if not stop:
            self.queue.append((next_probe(b, self.probed + self.given_up, self.cfg, observed), False, "straddle"))
        return stop, why

    # -- output ------------------------------------------------------------------------------------
    def _map(self, b: Belief) -> MapSnapshot:
        """The map the inclusions are detected on: with the detect rule the measured cells and the GP mean near them
        (models.adaptive_detect.candidate_map); with lse the GP mean (the belief alone)."""
        grid = self.grid.snapshot()
        if self.cfg.stop_rule == "detect":
            return candidate_map(b, grid.stiffness, grid.count, self.cfg)
        return MapSnapshot(stiffness=b.mean, x_mm=b.x_mm, y_mm=b.y_mm, count=grid.count, spread=b.std,
                           resolution_mm=self.params.resolution_mm)

    def _detection(self, b: Belief) -> tuple[MapSnapshot, Detection]:
        """:meth:`_map` and what the map detector (models.detector, the raster's own) finds on it: with the detect
        rule its background and noise from the stiffness-blind probes' cells (models.adaptive_detect)."""
        if self.cfg.stop_rule == "detect":
            grid = self.grid.snapshot()
            return detect_candidates(b, grid.stiffness, grid.count, self.cfg, self.fair.snapshot().stiffness)
        snap = self._map(b)
        return snap, detect(snap, detector_config(self.cfg))

    def _publish_belief(self, snap: MapSnapshot, final: bool) -> None:
        """The belief's mean and spread and the map ``snap`` (:meth:`_map`) on their topics."""
        b = self.belief
        assert b is not None
        now = self.clock.now_ns()
        for pub, grid in ((self.mean_pub, b.mean), (self.std_pub, b.std), (self.map_pub, snap.stiffness)):
            pub.publish(StiffnessMap(stamp_ns=now, unit=self.unit, x_mm=b.x_mm.tolist(), y_mm=b.y_mm.tolist(),
                                     stiffness=grid.ravel().tolist(), count=snap.count.ravel().tolist(),
                                     spread=b.std.ravel().tolist(), samples=len(self.probed), final=final))

    def _unsensed(self) -> tuple[list[tuple[float, float]], npt.NDArray[np.bool_]]:
        """Where an inclusion of the sizes of interest could still lie unseen (models.adaptive_detect.unsensed),
        said in the log: the stop rule bounds it, a user should still see where it is."""
        snap = self.grid.snapshot()
        # the points given up were never measured: where only they would have sensed, the report says unsensed
        hiding, mask = unsensed(np.isfinite(snap.stiffness), snap.x_mm, snap.y_mm, self.probed, self.cfg)
        (r0, f0), (r1, f1) = hiding[0], hiding[-1]
        self.log.info("unsensed: an inclusion sensed from at most %.1f mm away (the smallest of interest) could lie "
                      "unseen in %.1f %% of the region, one sensed from %.1f mm (the largest) in %.1f %% (map.png's "
                      "grey; the reach is a model: a small deep inclusion is sensed only from nearer)",
                      r0, 100 * f0, r1, 100 * f1)
        return hiding, mask

    def finish(self, why: str) -> None:
        self.done = True
        p = self.params
        elapsed = (self.clock.now_ns() - (self.started_ns or 0)) / 1e9
        self.log.info("stopping: %s (%d probes, %d refusals, %.1f s)", why, len(self.probed), self.refused, elapsed)
        out = Path(p.output_dir)
        hiding, mask = self._unsensed() if self.cfg.stop_rule == "detect" else ([], None)
        lost = self._losses()
        if lost:
            self.log.error("the map is INCOMPLETE: %s", lost)
        try:
            self._write(out, why, elapsed, hiding, mask, lost)
        except OSError as exc:   # map_output.MapNotWritten, or planner.json's own
            # without its map the scan has no result, and saying nothing would leave the graph waiting on a planner
            # that is done (the launch hung until killed)
            why_not = exc if isinstance(exc, MapNotWritten) else f"the map could not be written to {out}: {exc}"
            self.log.error("%s: the scan has no map (its samples are in the recording, if one was made)", why_not)
            lost = lost or str(why_not)
        self.timer(0.2, lambda: self.request_shutdown(1 if lost else 0), oneshot=True)

    def _write(self, out: Path, why: str, elapsed: float, hiding: list[tuple[float, float]],
               mask: npt.NDArray[np.bool_] | None, lost: str) -> None:
        """The final detection published and written with the map (map.npz, map.png, inclusions.json) and
        planner.json; raises OSError when a file cannot be written."""
        p = self.params
        found: dict[str, float] = {}
        if self.belief is not None:
            snap, det = self._detection(self.belief)
            # what a false-alarm law of the planner's own maps is fitted on (bench/detector_calibration.py)
            found = {"peak_significance": round(peak_significance(det), 4), "area_mm2": det.area_mm2,
                     "threshold_snr": round(det.threshold_snr, 4), "budget_fraction": self.cfg.budget_fraction}
            self._publish_belief(snap, final=True)
            title = (p.title or "adaptive palpation") + f"\n{len(self.probed)} probes; "
            title += detection_summary(det, p.false_alarm_per_map)
            write_outputs(out, snap, det.inclusions, unit=self.unit or "?", title=title, unsensed=mask,
                          incomplete=lost, model=self.cfg.model,
                          layers={"measured": self.grid.snapshot().stiffness, "fair": self.fair.snapshot().stiffness},
                          planner=planner_settings(p, self.cfg.region_mm))
            self.inc_pub.publish(inclusions_message(det, stamp_ns=self.clock.now_ns(), unit=self.unit,
                                                    false_alarm_per_map=p.false_alarm_per_map, final=True))
        else:
            self.inc_pub.publish(Inclusions(stamp_ns=self.clock.now_ns(), unit=self.unit, final=True,
                                            baseline=float("nan"), inclusions=[]))
        out.mkdir(parents=True, exist_ok=True)
        write_beside(out / "planner.json", json.dumps({
            "probes": len(self.probed), "refused": self.refused, "sim_s": elapsed, "stop": why,
            "swept_mm": len(self.probed) * (p.length_mm if p.mode == "sweep" else 0.0),
            "points": self.probed, "why": self.why, "given_up": self.given_up, "incomplete": lost,
            "unsensed": [{"reach_mm": r, "fraction": round(f, 4)} for r, f in hiding], "detection": found},
            indent=1) + "\n")

    def _losses(self) -> str:
        """What the map lacks of what was asked for or measured ('' when nothing): the map itself, probes given up
        after the scanner's refusals, estimates lost on the way or a restarted estimator. Then the run is not clean: the
        node exits 1 and planner.json's ``incomplete`` says why."""
        lost = []
        if self.belief is None:
            lost.append("no valid stiffness estimate reached the planner: there is no map")
        if self.given_up:
            lost.append(f"{len(self.given_up)} probe(s) given up after refusals, at "
                        + ", ".join(f"({x:.1f}, {y:.1f})" for x, y in self.given_up) + " mm: not in the map")
        stats = self.counters().get(self.resolve("stiffness/sample"))
        if stats is not None and stats.loss():
            lost.append(f"stiffness/sample {stats.loss()}")
        return "; ".join(lost)
