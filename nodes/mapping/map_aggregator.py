"""Map aggregator node: valid ``stiffness/sample`` messages -> a gridded map, detected inclusions, files.

Publishes the map (``map/stiffness``) and inclusions (``map/inclusions``), both latched, at ``publish_hz`` while
scanning; when the scan reports ``done`` on ``robot/scan_status`` it writes ``map.npz``, ``map.png`` and
``inclusions.json`` into ``output_dir`` (each file atomically). It writes once per scan: a repeated ``done`` (a
scanner lingering, a replay) writes nothing new, and shutdown writes only samples no file holds yet (a scan
stopped half-way), so a node asked to stop after its scan exits at once. The service ``map/save``
(:class:`Trigger` -> :class:`MapSaved`) writes them now, mid-scan. A map written before its scan is done (saved
mid-scan, or the scan stopped by a fault) says so: ``map.npz``'s ``incomplete`` and ``map.png``'s title tell how far
the scan got and how it ended, as they tell of samples lost on the way, and of a stretch of the scan's path over
which no estimate came at all (its producer stopped: ``max_silence_s``). A final map that holds only part of its
scan, whatever stopped it (a fault, Ctrl-C, a dead estimator), fails the node (exit code 1), so the launch cannot
end clean with it.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import palpa
from messages import (
    Inclusions,
    MapSaved,
    ScanPlan,
    ScanStatus,
    StiffnessMap,
    StiffnessSample,
    Trigger,
)
from models.detector import Detection, DetectorConfig, detect, false_alarm_law, with_law_of
from models.stiffness_map import MapSnapshot, StiffnessGrid, spacing_warning
from nodes.mapping.map_output import (
    MapNotWritten,
    PngHelper,
    detection_summary,
    inclusions_message,
    write_outputs,
)
from palpa.node.service import RequestRefused

__all__ = ["MapAggregator"]

_NOT_IN_CONTACT = ("no_contact", "too few indenters in contact")
"""Reasons (as they start) of a reading with the probe off the tissue, the air-float's and the camera probe's: a
raster's moves between presses, not an exclusion."""


class MapAggregator(palpa.Node):
    """Bins samples, detects inclusions, writes the scan's outputs."""


    class Params(palpa.Params):
        output_dir: str = "out"
        region_mm: list[float] = []
        """x0, y0, x1, y1 of the grid; empty: taken from the scan plan (``robot/plan``)."""
        resolution_mm: palpa.Positive = 2.0
        min_count: palpa.PositiveInt = 3
        """Samples a cell needs to count."""
        publish_hz: palpa.Positive = 1.0
        false_alarm_per_map: palpa.Positive = 0.003
        """The detector's threshold: the chance that a map without inclusions shows a detection (models.detector)."""
        radii_mm: tuple[float, ...] = (2.5, 3.5, 5.0, 7.0)
        """The inclusion radii the detector's matched filter looks for."""
        title: str = ""
        """Shown on map.png (e.g. what was scanned); default: the output directory."""
        max_excluded: palpa.NonNegative = 0.2
        """Largest fraction of the raster's readings in contact that may be excluded (invalid for any reason but
        the probe off the tissue: the ring off the specimen, the indenter on its stop, stale inputs) before the map counts as
        untrustworthy: it is then marked incomplete and fails."""
        max_silence_s: palpa.Positive = 2.0
        """Simulated seconds of scanning with no ``stiffness/sample`` at all (valid or not) after which the
        estimates count as missing: the map then says over which part of the scan's path it had none, and fails."""
        png_helper: bool = False
        """Start a process at set-up that imports matplotlib while the scan runs and draws map.png at the end
        (nodes.mapping.map_output.PngHelper): the scan's end comes ~0.3 s sooner where a core is free."""

    params: Params

    def setup(self) -> None:
        p = self.params
        self.map_pub = self.publisher("map/stiffness", StiffnessMap, latched=True)
        self.inc_pub = self.publisher("map/inclusions", Inclusions, latched=True)
        self.grid: StiffnessGrid | None = None
        self.warned_spacing = 0.0
        self.unit = ""
        self.model = ""
        """The estimator's model (``stiffness/sample``'s): it picks the detector's false-alarm law."""
        self.detector = DetectorConfig(radii_mm=tuple(p.radii_mm), false_alarm_per_map=p.false_alarm_per_map)
        self.samples = 0
        self.pending: list[tuple[float, float, float]] = []
        self.written = 0
        self.changed = False
        self.incomplete = ""
        self.png_helper = self.closing(PngHelper()) if p.png_helper else None
        """Why this map lacks data the scan produced ('' when it has everything): it is then declared failed."""
        self.scan: ScanStatus | None = None
        """The raster scan's latest status, once it has been seen scanning (not a scanner serving probes): a map
        written before it is ``done`` holds only part of the scan and says so."""
        self.unsaved = 0
        """Samples taken since the files were last written."""
        self.heard_ns = 0
        """When the latest estimate (valid or not) came, or the raster began: the producer's sign of life."""
        self.heard_progress = 0.0
        """The scan's progress then."""
        self.silent_from: float | None = None
        """The scan's progress when the estimates stopped coming (None: they come)."""
        self.excluded: dict[str, int] = {}
        """Per reason, the raster's readings in contact that were not stiffness readings (invalid, not no_contact)."""
        self.in_raster = 0
        """The raster's valid readings."""
        self.gaps: list[tuple[float, float]] = []
        """Spans of the scan's path (progress from, to) over which no estimate came."""
        self.touching = False
        self.raster_from_ns = 0
        """Samples measured before the raster began (the scanner's touch-off finding the surface) are not mapped."""
        if p.region_mm:
            if len(p.region_mm) != 4:
                raise palpa.ParamError(f"{self.name}: region_mm needs x0, y0, x1, y1, got {p.region_mm}")
            self._make_grid(*p.region_mm)
        self.subscribe("stiffness/sample", self.on_sample)
        self.subscribe("robot/plan", self.on_plan)
        self.subscribe("robot/scan_status", self.on_status)
        self._own = self.subscribe("map/stiffness", StiffnessMap, self._on_own_map)
        self.timer(1.0 / p.publish_hz, self.publish_map)
        self.service("map/save", Trigger, MapSaved, self.on_save)

    def on_save(self, req: Trigger) -> MapSaved:
        """Service ``map/save``: write the map files from what has been received so far."""
        if self.grid is None or not self.samples:
            raise RequestRefused("no map to save yet (no valid stiffness sample received)")
        self._bin_pending()
        snap = self.grid.snapshot()
        try:
            paths = self.write(snap, self._detect(snap))
        except MapNotWritten as exc:
            raise RequestRefused(str(exc)) from None
        return MapSaved(paths=[str(p) for p in paths], samples=self.samples)

    def _make_grid(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.grid = StiffnessGrid(x0, y0, x1, y1, self.params.resolution_mm, min_count=self.params.min_count)
        self._bin_pending()

    def _bin_pending(self) -> None:
        """Bin the samples received since the last snapshot in one call (one numpy call per sample cost more than
        the rest of the node)."""
        if self.grid is not None and self.pending:
            xs, ys, vs = zip(*self.pending, strict=True)
            self.grid.add(np.array(xs), np.array(ys), np.array(vs))
            self.pending.clear()

    def on_plan(self, plan: ScanPlan) -> None:
        warning = spacing_warning(plan.spacing_mm, self.params.resolution_mm)
        if warning and plan.spacing_mm != self.warned_spacing:
            self.warned_spacing = plan.spacing_mm
            self.log.warning("%s", warning)
        if self.grid is None:
            # half a cell of margin: raster lines and grid points on the region's edges fall on cell centres
            h = self.params.resolution_mm / 2
            x0, y0, x1, y1 = plan.region_mm
            self._make_grid(x0 - h, y0 - h, x1 + h, y1 + h)
            self.log.info("map region from the scan plan: %s mm (cells centred on the raster)", plan.region_mm)

    def on_sample(self, s: StiffnessSample) -> None:
        self._heard()
        if self.touching or s.stamp_ns < self.raster_from_ns:
            return
        if self.scan is not None and self.scan.state == "scanning":
            if s.valid:
                self.in_raster += 1
            elif not s.reason.startswith(_NOT_IN_CONTACT):
                self.excluded[s.reason] = self.excluded.get(s.reason, 0) + 1
        if not s.valid:
            return
        self.unit = s.unit
        if s.model != self.model:
            self._take_model(s.model)
        self.samples += 1
        self.unsaved += 1
        self.changed = True
        self.pending.append((s.x_mm, s.y_mm, s.value))

    def _on_own_map(self, m: StiffnessMap) -> None:
        """The latched map of an earlier incarnation of this node (it was killed and respawned mid-scan): what it
        had accumulated is gone, so this map cannot be complete."""
        h = self._own.last_header
        if h is None or h.node != self.name or h.inc == self.incarnation or m.final or not m.samples:
            return
        if not self.incomplete:
            self.incomplete = (f"this node restarted mid-scan: its previous run had mapped {m.samples} samples, "
                               "which are lost")
            self.log.error("map INCOMPLETE: %s", self.incomplete)

    def _heard(self) -> None:
        """An estimate came: the producer is alive; a stretch of the path without estimates ends here."""
        progress = self.scan.progress if self.scan is not None else 0.0
        if self.silent_from is not None:
            self.gaps.append((self.silent_from, progress))
            self.log.warning("stiffness estimates again at %.0f %% of the scan's path", 100 * progress)
            self.silent_from = None
        self.heard_ns, self.heard_progress = self.clock.now_ns(), progress

    def _watch_estimates(self, st: ScanStatus) -> None:
        """While the raster runs, estimates must keep coming: a stretch of the scan's path without any is missing
        from the map (module doc), however its producer stopped."""
        now = self.clock.now_ns()
        if self.scan is None or self.scan.state != "scanning":
            self.heard_ns, self.heard_progress = now, st.progress  # the raster (re)starts: count from here
            return
        if self.silent_from is None and now - self.heard_ns > self.params.max_silence_s * 1e9:
            self.silent_from = self.heard_progress
            self.log.error("no stiffness/sample for %.1f s while scanning (since %.0f %% of the scan's path): the "
                           "map is missing estimates", (now - self.heard_ns) / 1e9, 100 * self.heard_progress)

    def on_status(self, st: ScanStatus) -> None:
        if st.state == "scanning":
            self._watch_estimates(st)
        if st.state == "scanning" or self.scan is not None:
            self.scan = st
        if st.state == "touching":
            self.touching = True
        elif self.touching:  # the touch-off is over: map only what is measured from now on
            self.touching, self.raster_from_ns = False, st.stamp_ns
        if st.state == "done" and (self.unsaved or not self.written):
            self.log.info("scan done: writing the map")
            self.publish_map(final=True)

    def _take_model(self, model: str) -> None:
        """The samples come from ``model``'s estimator: detect with the false-alarm law measured for that probe."""
        self.model = model
        if false_alarm_law(model) is None:
            self.log.warning("no false-alarm law was measured for %r maps (models.false_alarm.FALSE_ALARM_LAWS): the "
                             "air-float probe's is used, so the stated false-alarm rate is not this map's "
                             "(bench/detector_calibration.py measures one on blank scans)", model)
        self.detector = with_law_of(replace(self.detector, gumbel=DetectorConfig().gumbel), model)

    def _detect(self, snap: MapSnapshot) -> Detection:
        return detect(snap, self.detector)

    def publish_map(self, final: bool = False) -> None:
        if self.grid is None or (not self.changed and not final):
            return
        if final:
            self._check_complete()
        self.changed = False
        self._bin_pending()
        snap = self.grid.snapshot()
        det = self._detect(snap)
        now = self.clock.now_ns()
        self.map_pub.publish(StiffnessMap(
            stamp_ns=now, unit=self.unit, x_mm=snap.x_mm.tolist(), y_mm=snap.y_mm.tolist(),
            stiffness=snap.stiffness.ravel().tolist(), count=snap.count.ravel().astype(int).tolist(),
            spread=snap.spread.ravel().tolist(), samples=self.samples, final=final,
        ))
        self.inc_pub.publish(inclusions_message(det, stamp_ns=now, unit=self.unit,
                                                false_alarm_per_map=self.params.false_alarm_per_map, final=final))
        if final:
            with contextlib.suppress(MapNotWritten):   # said, and the exit code is 1
                self.write(snap, det)

    def write(self, snap: MapSnapshot, det: Detection) -> list[Path]:
        out = Path(self.params.output_dir)
        found = det.inclusions
        title = self.params.title or f"stiffness map — {out}"
        title += f"\n{self.samples} samples, {time.strftime('%Y-%m-%d %H:%M')}; "
        title += detection_summary(det, self.params.false_alarm_per_map)
        partial = self._partial()
        if partial:
            self.log.warning("the map written holds part of the scan: %s", partial)
        try:
            paths = write_outputs(out, snap, found, unit=self.unit or "?", title=title, incomplete=partial,
                                  helper=self.png_helper, model=self.model)
        except MapNotWritten as exc:   # the scan has no map, and must not end as if it had one
            self.log.error("%s: the scan has no map (its samples are in the recording, if one was made)", exc)
            self.exit_code = 1
            raise
        self.written += 1
        self.unsaved = 0
        for inc in found:
            self.log.info("inclusion at (%.1f, %.1f) mm, radius %.1f mm, contrast %.2f, SNR %.1f, false-alarm "
                          "probability %.2g per map", inc.x_mm, inc.y_mm, inc.radius_mm, inc.contrast, inc.snr,
                          inc.false_alarm)
        self.log.info("map written: %s", ", ".join(str(p) for p in paths))
        return list(paths)

    def _unfinished(self) -> str:
        """'' once the scan is done (or when no raster scan was seen); else how far it got and how it ended."""
        scan = self.scan
        if scan is None or scan.state == "done":
            return ""
        how = f"it ended {scan.state}" if scan.state in ("fault", "estop", "stopped") else f"last heard {scan.state}"
        return (f"the scan did not finish: {how} at {100 * scan.progress:.0f} % of its path"
                + (f" ({scan.message})" if scan.message else ""))

    def _missing(self) -> str:
        """'' when estimates came all along the raster; else over which part of the scan's path none came."""
        gaps = list(self.gaps)
        if self.silent_from is not None:
            end = self.scan.progress if self.scan is not None else self.silent_from
            gaps.append((self.silent_from, 1.0 if self.scan is not None and self.scan.state == "done" else end))
        if not gaps:
            return ""
        spans = ", ".join(f"{100 * a:.0f} % to {100 * b:.0f} %" for a, b in gaps)
        return f"no stiffness estimate came from {spans} of the scan's path (did the estimator stop?)"

    def _untrusted(self) -> str:
        """'' unless more than ``max_excluded`` of the raster's readings in contact were not stiffness readings."""
        n = sum(self.excluded.values())
        if not n or n <= self.params.max_excluded * (n + self.in_raster):
            return ""
        reasons = ", ".join(f"{why} {k}" for why, k in sorted(self.excluded.items(), key=lambda kv: -kv[1]))
        return (f"{100 * n / (n + self.in_raster):.0f} % of the raster's readings in contact were not stiffness "
                f"readings ({reasons}; at most {100 * self.params.max_excluded:.0f} % may be): the map cannot be "
                "trusted")

    def _partial(self) -> str:
        """Why this map holds only part of its scan, or cannot be trusted ('' when neither)."""
        return "; ".join(filter(None, (self.incomplete, self._missing(), self._untrusted(), self._unfinished())))

    def _check_complete(self) -> None:
        """A final map that holds part of its scan (its estimator restarted or stopped, samples lost on the way,
        the scan stopped before its end) is declared failed: the node's exit code says so, so the launch cannot
        end clean."""
        stats = self.counters().get(self.resolve("stiffness/sample"))
        if not self.incomplete and stats is not None and stats.loss():
            self.incomplete = f"stiffness/sample {stats.loss()}"
        partial = self._partial()
        if partial:
            self.log.error("the map is INCOMPLETE and may be wrong: %s", partial)
            self.exit_code = 1

    def on_shutdown(self) -> None:
        if self.grid is not None and self.unsaved:
            self.log.info("stopping with %d samples not yet written: writing the map", self.unsaved)
            self.publish_map(final=True)
        elif self.written and self.samples:
            self._check_complete()  # written before (saved mid-scan): what it holds is still only part of it


if __name__ == "__main__":
    palpa.run_node(MapAggregator)
