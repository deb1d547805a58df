"""The scanner's specimen: its region, the prior surface, the touch-off that finds the real one
(:class:`nodes.scanner.touchoff.TouchOff`) and the raster's surface after it. Split from nodes/scanner/touchoff.py, which drives the
arm; this decides where and with what."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import palpa
from messages import IndenterDisplacements, ProbeHeights
from models.airfloat import DEFAULT_SPS_RADIUS_MM
from models.geometry import GeometryError, load_geometry
from models.surface import (
    SpecimenDoesNotFit,
    SurfaceFit,
    check_fits,
    fit_surface,
    flat_surface,
    region_from_touches,
    region_in_footprint,
    search_points,
    touch_points,
)
from nodes.drivers.robot import RobotDriver
from nodes.scanner.scanner_params import ScannerParams
from nodes.scanner.touchoff import TouchOff, TouchOffConfig

__all__ = ["SpecimenPlanner"]

_DEFAULT_THRESHOLD = {"heights": 9.0, "indenters": 0.3, "force": 0.5}
_TABLE_CLEARANCE_MM = DEFAULT_SPS_RADIUS_MM + 1.0
"""Bare table a table point needs around it: the SPS ring's radius and a millimetre (the ring must see table only)."""


class SpecimenPlanner:
    """The scanner's specimen: its region (given, or the measured footprint less a margin), the prior surface
    (the measured thickness), the touch-off that finds the real one, and the raster's surface after it.

    Everything that can be refused is refused in the constructor, before any motion: a region or a specimen
    height the workspace box cannot hold raises ``palpa.ParamError`` naming the box and the extent.
    """

    def __init__(self, params: ScannerParams, name: str, driver: RobotDriver) -> None:
        self.params = params
        self.search_box: tuple[float, ...] | None = None
        p = params
        box = p.workspace_mm
        geo = None
        if p.geometry:
            try:
                geo = load_geometry(p.geometry)
            except GeometryError as exc:
                raise palpa.ParamError(f"{name}: geometry: {exc}") from None
        footprint = geo.footprint_mm() if geo is not None else None
        try:
            if p.region_mm:
                if len(p.region_mm) != 4:
                    raise palpa.ParamError(f"{name}: region_mm needs x0, y0, x1, y1, got {p.region_mm}")
                self.region = (float(p.region_mm[0]), float(p.region_mm[1]), float(p.region_mm[2]),
                               float(p.region_mm[3]))
                what = "the scan region (region_mm)"
            elif p.search_box_mm:
                self.search_box = _search_box(name, p.search_box_mm, p.touchoff, box)
                sb = self.search_box
                self.region, what = (sb[0], sb[1], sb[3], sb[4]), "the search box (search_box_mm)"
            elif footprint is not None:
                self.region = region_in_footprint(footprint, p.edge_margin_mm)
                what = (f"the specimen's footprint x {footprint[0]:g}..{footprint[2]:g}, y {footprint[1]:g}.."
                        f"{footprint[3]:g} mm less the {p.edge_margin_mm:g} mm edge margin,")
            elif not p.autostart:  # serving probe_at only: no raster will run; a point plan at home passes checks
                hx, hy = p.home_mm[0], p.home_mm[1]
                self.region, what = (hx, hy, hx, hy), "the home position"
            else:
                raise palpa.ParamError(f"{name}: no scan region: give region_mm (x0, y0, x1, y1 mm), a "
                                       "search_box_mm to find the specimen in, or a geometry file with its footprint")
            top = geo.top_mm() if geo is not None else None
            clearance = p.search_clearance_mm if p.touchoff != "off" else p.retract_clearance_mm
            check_fits(self.region, box, top_mm=top, clearance_mm=clearance, what=what)
        except (SpecimenDoesNotFit, ValueError) as exc:
            raise palpa.ParamError(f"{name}: refusing the specimen before any motion: {exc}") from None
        self.prior_top = top
        self.table_point = _table_point(name, p, footprint or self.region) if p.table_point_mm else None
        self.table_z_mm: float | None = None
        """The table's height at ``table_point`` once touched (None: not touched)."""
        # until the touch-off has run, heights are over a level surface: the flat contact_z_mm, or the thickest
        # measured point (so that the pre-motion check of the plan sees the specimen's real height)
        self.surface: SurfaceFit | None = None if p.touchoff == "off" else flat_surface(top if top is not None else 0.0)
        self.touch: TouchOff | None = None
        if p.touchoff != "off":
            start = (top + p.search_clearance_mm) if top is not None else box[5] - 1.0
            cfg = TouchOffConfig(signal=p.touchoff, start_z_mm=min(start, box[5] - 0.5), floor_z_mm=box[2],
                                 search_speed_mm_s=p.search_speed_mm_s, transit_speed_mm_s=p.transit_speed_mm_s,
                                 accel_mm_s2=p.accel_mm_s2,
                                 threshold=p.touch_threshold or _DEFAULT_THRESHOLD[p.touchoff])
            if self.search_box is not None:  # from the box's top down to its floor, at every point of a grid
                sb = self.search_box
                cfg = dataclasses.replace(cfg, start_z_mm=sb[5], floor_z_mm=sb[2], search=True)
                points = search_points(self.region, p.search_step_mm)
            else:
                i = p.touch_inset_mm
                x0, y0, x1, y1 = self.region
                inner = (x0 + i, y0 + i, x1 - i, y1 - i) if x1 - x0 > 2 * i and y1 - y0 > 2 * i else self.region
                points = touch_points(inner, p.touch_grid)
            if self.table_point is not None:  # the table first, beside the specimen
                points, cfg = [self.table_point, *points], dataclasses.replace(cfg, table_points=1)
            self.touch = TouchOff(driver, points, cfg)

    def plan_heights(self) -> dict[str, object]:
        """Keyword arguments of the raster functions for the heights: flat, or over the surface."""
        p = self.params
        if self.surface is None:
            return {"contact_z_mm": p.contact_z_mm}
        if p.mode == "sweep":
            return {"contact_z_mm": p.working_offset_mm, "surface": self.surface}
        return {"contact_z_mm": 0.0, "surface": self.surface}

    def plan_z(self) -> Callable[[float, float], float] | None:
        """A sweep's planned face height at (x, y) over the found surface (None: no surface)."""
        surface, offset = self.surface, self.params.working_offset_mm
        if surface is None:
            return None
        return lambda x, y: surface.z(x, y) + offset

    def press_depth_mm(self) -> float:
        """Indent depth: the set depth, but never more than ``max_press_fraction`` of the thinnest found point nor
        closer than 0.2 mm to the workspace box's floor."""
        p = self.params
        if self.surface is None or self.touch is None:
            return float(p.indent_depth_mm)
        # before the touch-off the plan is checked over the thickest measured point; after it, the thinnest found
        thinnest = min(z for _, _, z in self.touch.touches) if self.touch.done else (self.prior_top or math.inf)
        floor = thinnest - p.workspace_mm[2] - 0.2  # and never within 0.2 mm of the box's floor
        return float(max(0.1, min(p.indent_depth_mm, p.max_press_fraction * thinnest, floor)))

    def on_probe(self, msg: ProbeHeights | IndenterDisplacements) -> None:
        if self.touch is None:
            return
        if isinstance(msg, ProbeHeights):
            self.touch.on_heights(msg.stamp_ns, msg.h_mm, msg.valid)
        else:
            self.touch.on_indenters(msg.stamp_ns, msg.displacement_mm, msg.valid)

    def finish_touch(self) -> str:
        """Fit the surface through the touches; returns a line for the log (raises ValueError if it cannot)."""
        if self.touch is None:
            raise ValueError("no touch-off ran")
        found = ""
        if self.search_box is not None:
            sb, p = self.search_box, self.params
            self.region = region_from_touches(self.touch.touches, p.edge_margin_mm, (sb[0], sb[1], sb[3], sb[4]))
            xs, ys = [t[0] for t in self.touch.touches], [t[1] for t in self.touch.touches]
            found = (f"search: the specimen under {len(xs)} of {len(xs) + len(self.touch.misses)} points, extent x "
                     f"{min(xs):g}..{max(xs):g}, y {min(ys):g}..{max(ys):g} mm; region x {self.region[0]:g}.."
                     f"{self.region[2]:g}, y {self.region[1]:g}..{self.region[3]:g} mm; ")
        table = ""
        if self.touch.table_touches:
            tx, ty, self.table_z_mm = self.touch.table_touches[0]
            table = f"the table at z {self.table_z_mm:.2f} mm beside the specimen at ({tx:g}, {ty:g}) mm; "
        fit = fit_surface(self.touch.touches)
        self.surface = fit
        zs = [z for _, _, z in self.touch.touches]
        slower = (f"; {self.touch.reapproaches} descents repeated more slowly (the force rose in too few readings)"
                  if self.touch.reapproaches else "")
        return (f"{found}{table}touch-off: {len(zs)} points, surface {min(zs):.2f}..{max(zs):.2f} mm, {fit.model} fit "
                f"(rms {fit.rms_mm:.3f} mm){slower}")


def _table_point(name: str, p: ScannerParams, specimen: tuple[float, float, float, float]) -> tuple[float, float]:
    """table_point_mm checked before any motion: two numbers, a heights touch-off to read the table with, inside the
    workspace box (the arm goes there), and the SPS ring clear of ``specimen`` (its footprint, else the region) by
    :data:`_TABLE_CLEARANCE_MM` (on it, the SPS would read the specimen's surface for the table)."""
    v = p.table_point_mm
    if len(v) != 2 or not all(math.isfinite(float(c)) for c in v):
        raise palpa.ParamError(f"{name}: table_point_mm needs x, y (mm, phantom frame), got {list(v)}")
    if p.touchoff != "heights":
        raise palpa.ParamError(f"{name}: table_point_mm needs touchoff: heights (the probe's SPS read the table from "
                               f"above, the face never reaches it); touchoff is {p.touchoff}")
    x, y = float(v[0]), float(v[1])
    b = p.workspace_mm
    if not (b[0] <= x <= b[3] and b[1] <= y <= b[4]):
        raise palpa.ParamError(f"{name}: refusing the table touch before any motion: table_point_mm ({x:g}, {y:g}) "
                               f"mm lies outside the workspace box (x {b[0]:g}..{b[3]:g}, y {b[1]:g}..{b[4]:g} mm): "
                               "the arm may not go there")
    x0, y0, x1, y1 = specimen
    gap = math.hypot(max(x0 - x, 0.0, x - x1), max(y0 - y, 0.0, y - y1))
    if gap < _TABLE_CLEARANCE_MM:
        raise palpa.ParamError(f"{name}: refusing the table touch before any motion: table_point_mm ({x:g}, {y:g}) mm "
                               f"is {gap:.1f} mm from the specimen (x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm); the SPS "
                               f"ring needs {_TABLE_CLEARANCE_MM:g} mm of bare table around the point")
    return x, y


def _search_box(name: str, values: Sequence[float], signal: str,
                box: tuple[float, float, float, float, float, float]) -> tuple[float, ...]:
    """search_box_mm checked: six numbers, a box inside the workspace, and a contact signal to search with."""
    if signal == "off":
        raise palpa.ParamError(f"{name}: search_box_mm needs a contact signal to find the specimen with: touchoff "
                               "heights, force or indenters (it is off)")
    sb = tuple(float(v) for v in values)
    if len(sb) != 6 or not all(math.isfinite(v) for v in sb) or not (sb[0] <= sb[3] and sb[1] <= sb[4]
                                                                     and sb[2] < sb[5]):
        raise palpa.ParamError(f"{name}: search_box_mm needs xmin, ymin, zmin, xmax, ymax, zmax (mm) with zmin < zmax, "
                               f"got {list(values)}")
    if sb[2] < box[2] or sb[5] > box[5]:
        raise SpecimenDoesNotFit(f"the search box's heights z {sb[2]:g}..{sb[5]:g} mm leave the workspace box (x "
                                 f"{box[0]:g}..{box[3]:g}, y {box[1]:g}..{box[4]:g}, z {box[2]:g}..{box[5]:g} mm)")
    return sb
