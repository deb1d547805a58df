"""Map aggregator node: valid ``stiffness/sample`` messages -> a gridded map, detected inclusions, files.

Publishes the map (``map/stiffness``) and inclusions (``map/inclusions``), both latched, at ``publish_hz`` while
scanning; when the scan reports ``done`` on ``robot/scan_status`` it writes ``map.npz``, ``map.png`` and
``inclusions.json`` into ``output_dir`` (each file atomically). It writes once per scan: a repeated ``done`` (a
scanner lingering, a replay) writes nothing new, and shutdown writes only samples no file holds yet (a scan
stopped half-way), so a node asked to stop after its scan exits at once. The service ``map/save``
(:class:`Trigger` -> :class:`MapSaved`) writes them now, mid-scan. A map written before its scan is done (saved
mid-scan, or the scan stopped by a fault) says so: ``map.npz``'s ``incomplete`` and ``map.png``'s title tell how far
the scan got and how it ended, as they tell of samples lost on the way.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import palpa
from messages import (
    DetectedInclusion,
    Inclusions,
    MapSaved,
    ScanPlan,
    ScanStatus,
    StiffnessMap,
    StiffnessSample,
    Trigger,
)
from models.stiffness_map import (
    Inclusion,
    MapSnapshot,
    StiffnessGrid,
    background,
    detect_inclusions,
)
from nodes.mapping.map_output import PngHelper, write_outputs
from palpa.node.service import RequestRefused

__all__ = ["MapAggregator"]


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
        k_mad: palpa.NonNegative = 4.0
        rel_threshold: palpa.NonNegative = 0.2
        """A cell is stiff above baseline + max(k_mad * robust σ, rel_threshold * baseline)."""
        min_area_mm2: palpa.NonNegative = 0.0
        """Smallest inclusion reported (0: two cells)."""
        title: str = ""
        """Shown on map.png (e.g. what was scanned); default: the output directory."""
        png_helper: bool = False
        """Start a process at set-up that imports matplotlib while the scan runs and draws map.png at the end
        (nodes.mapping.map_output.PngHelper): the scan's end comes ~0.3 s sooner where a core is free."""

    params: Params

    def setup(self) -> None:
        p = self.params
        self.map_pub = self.publisher("map/stiffness", StiffnessMap, latched=True)
        self.inc_pub = self.publisher("map/inclusions", Inclusions, latched=True)
        self.grid: StiffnessGrid | None = None
        self.unit = ""
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
        paths = self.write(snap, self._detect(snap)[0])
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
        if self.grid is None:
            # half a cell of margin: raster lines and grid points on the region's edges fall on cell centres
            h = self.params.resolution_mm / 2
            x0, y0, x1, y1 = plan.region_mm
            self._make_grid(x0 - h, y0 - h, x1 + h, y1 + h)
            self.log.info("map region from the scan plan: %s mm (cells centred on the raster)", plan.region_mm)

    def on_sample(self, s: StiffnessSample) -> None:
        if not s.valid or self.touching or s.stamp_ns < self.raster_from_ns:
            return
        self.unit = s.unit
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

    def on_status(self, st: ScanStatus) -> None:
        if st.state == "scanning" or self.scan is not None:
            self.scan = st
        if st.state == "touching":
            self.touching = True
        elif self.touching:  # the touch-off is over: map only what is measured from now on
            self.touching, self.raster_from_ns = False, st.stamp_ns
        if st.state == "done" and (self.unsaved or not self.written):
            self.log.info("scan done: writing the map")
            self.publish_map(final=True)

    def _detect(self, snap: MapSnapshot) -> tuple[list[Inclusion], float]:
        p = self.params
        try:
            found = detect_inclusions(snap, k_mad=p.k_mad, rel_threshold=p.rel_threshold,
                                      min_area_mm2=p.min_area_mm2 or None)
        except ValueError as exc:
            self.log.warning("no inclusion detection: %s", exc)
            found = []
        return found, background(snap.stiffness)[0]

    def publish_map(self, final: bool = False) -> None:
        if self.grid is None or (not self.changed and not final):
            return
        if final:
            self._check_complete()
        self.changed = False
        self._bin_pending()
        snap = self.grid.snapshot()
        found, base = self._detect(snap)
        now = self.clock.now_ns()
        self.map_pub.publish(StiffnessMap(
            stamp_ns=now, unit=self.unit, x_mm=snap.x_mm.tolist(), y_mm=snap.y_mm.tolist(),
            stiffness=snap.stiffness.ravel().tolist(), count=snap.count.ravel().astype(int).tolist(),
            spread=snap.spread.ravel().tolist(), samples=self.samples, final=final,
        ))
        self.inc_pub.publish(Inclusions(
            stamp_ns=now, unit=self.unit, baseline=float(base), final=final,
            inclusions=[DetectedInclusion(x_mm=i.x_mm, y_mm=i.y_mm, radius_mm=i.radius_mm, contrast=i.contrast)
                        for i in found],
        ))
        if final:
            self.write(snap, found)

    def write(self, snap: MapSnapshot, found: list[Inclusion]) -> list[Path]:
        out = Path(self.params.output_dir)
        title = self.params.title or f"stiffness map — {out}"
        title += f"\n{self.samples} samples, {len(found)} inclusion(s), {time.strftime('%Y-%m-%d %H:%M')}"
        partial = "; ".join(filter(None, (self.incomplete, self._unfinished())))
        if partial:
            self.log.warning("the map written holds part of the scan: %s", partial)
        paths = write_outputs(out, snap, found, unit=self.unit or "?", title=title, incomplete=partial,
                              helper=self.png_helper)
        self.written += 1
        self.unsaved = 0
        for inc in found:
            self.log.info("inclusion at (%.1f, %.1f) mm, radius %.1f mm, contrast %.2f",
                          inc.x_mm, inc.y_mm, inc.radius_mm, inc.contrast)
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

    def _check_complete(self) -> None:
        """A map missing samples (its estimator restarted, samples lost on the way) is declared failed: the
        node's exit code says so, so the launch cannot end clean."""
        stats = self.counters().get(self.resolve("stiffness/sample"))
        if not self.incomplete and stats is not None and stats.loss():
            self.incomplete = f"stiffness/sample {stats.loss()}"
        if self.incomplete:
            self.log.error("the map is INCOMPLETE and may be wrong: %s", self.incomplete)
            self.exit_code = 1

    def on_shutdown(self) -> None:
        if self.grid is not None and self.unsaved:
            self.log.info("stopping with %d samples not yet written: writing the map", self.unsaved)
            self.publish_map(final=True)


if __name__ == "__main__":
    palpa.run_node(MapAggregator)
