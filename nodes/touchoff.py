"""Touch-off: find the specimen's surface at a few points before the raster, as a rig does.

For each point the arm lifts to ``start_z_mm``, moves over the point and descends at ``search_speed_mm_s``
towards ``floor_z_mm`` while it watches a contact signal; at contact it stops, records the surface height there
and goes on to the next point. The contact signals (``signal``):

* ``heights`` -- the air-float probe's own surface-profile sensors: as soon as SPS1..3 read less than
  ``threshold`` (mm, inside their stroke) the probe sees the surface below its face, so the surface is the face
  height at that sample's stamp less the SPS mean (the median of ``samples`` readings). No force is needed.
* ``indenters`` -- the camera probe: an indenter moved more than ``threshold`` (mm) from where it was when the
  search over this point began (a tare: guide friction can hold an indenter in after the previous press); the
  surface is where they began to move (the samples since a quarter of the threshold extrapolated back to 0 along
  a line: springs).
* ``force`` -- the arm's TCP force (ur_rtde's ``actual_TCP_force``): |Fz| above ``threshold`` (N); the surface is
  the height where the force began: the samples from contact to ``threshold`` are fitted with F = (k (z0 - z))^p,
  p free in 1..2.5 (:func:`models.surface.contact_onset_z`), so that neither the tissue's stiffness nor how much
  a thin layer stiffens under the press biases it (a fixed Hertz 1.5 put the surface 0.1 mm low on a 6 mm dome).
  The force is read when :meth:`step` runs; if the rise went by in fewer than 4 readings (a descent too fast for a
  busy PC's steps), the arm backs up to 1 mm over the last force-free height and descends again at half the
  speed, up to three times (``reapproaches`` counts them).

A descent that reaches the floor without contact is an error naming the point (nothing under it); in a search for
the specimen (``search``, the scanner's ``search_box_mm``) it is a miss, and so is a ring half over an edge. The driver
is any :class:`nodes.drivers.robot.RobotDriver`; the scanner feeds probe data and calls :meth:`step` from its
timer. Pure logic apart from the driver: testable on the sim driver with a mock clock, and on the UR emulator.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import palpa
from messages import IndenterDisplacements, ProbeHeights
from models.geometry import GeometryError, load_geometry
from models.surface import (
    SpecimenDoesNotFit,
    SurfaceFit,
    check_fits,
    contact_onset_z,
    fit_surface,
    flat_surface,
    region_from_touches,
    region_in_footprint,
    search_points,
    touch_points,
)
from models.timeseries import StampedBuffer
from nodes.drivers.robot import MotionStatus, PathPoint, RobotDriver

if TYPE_CHECKING:
    from nodes.robot_scanner import RobotScanner

__all__ = ["SpecimenPlanner", "TouchOff", "TouchOffConfig"]

Signal = Literal["heights", "indenters", "force"]
_NEAR_MM = 0.5
_FORCE_POWERS = tuple(1.0 + 0.05 * k for k in range(31))  # a contact law's exponent: 1 (a spring) .. 2.5
_REAPPROACHES = 3


@dataclass(frozen=True)
class TouchOffConfig:
    """Heights (mm, phantom frame), speeds (mm/s), acceleration (mm/s^2); ``threshold`` in mm or N (see module)."""

    signal: Signal
    start_z_mm: float
    floor_z_mm: float
    search_speed_mm_s: float = 5.0
    transit_speed_mm_s: float = 40.0
    accel_mm_s2: float = 500.0
    threshold: float = 9.0
    samples: int = 5
    max_spread_mm: float = 3.0
    """heights: samples whose three SPS differ by more than this are ignored (one hangs over an edge)."""
    stroke_mm: float = 10.0
    """heights: the SPS's stroke; a reading at its end sees nothing."""
    search: bool = False
    """Searching for the specimen: a point with nothing under it (no contact down to the floor, a surface below the
    floor, or, heights, ``samples`` readings with an SPS ring half over an edge) is a miss, not an error."""


class TouchOff:
    """Runs the touch-off over ``points`` with ``driver``; ``touches`` holds (x, y, z_surface) when ``done``."""

    def __init__(self, driver: RobotDriver, points: Sequence[tuple[float, float]], config: TouchOffConfig) -> None:
        if not points:
            raise ValueError("touch-off: no points")
        if not config.floor_z_mm < config.start_z_mm:
            raise ValueError(f"touch-off: the floor z {config.floor_z_mm:g} mm must lie below the start height "
                             f"{config.start_z_mm:g} mm")
        self.driver, self.points, self.cfg = driver, list(points), config
        self.touches: list[tuple[float, float, float]] = []
        self.misses: list[tuple[float, float]] = []
        self._edge = 0  # heights, search: samples with the SPS ring half over an edge at this point
        self.index = 0
        self.phase: Literal["idle", "searching", "stopping", "lifting", "done", "failed"] = "idle"
        self.error = ""
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._found: list[float] = []
        self._rising: list[tuple[float, float]] = []  # (z, signal) since the contact signal began to rise
        self._tare: tuple[float, ...] | None = None  # indenters: their displacements when the search here began
        self._free_z: float | None = None  # force: the last height over this point with no force yet
        self._slower = 0  # force: re-approaches at this point (each at half the last descent's speed)
        self._again_from: float | None = None  # force: once stopped, descend again from this height
        self.reapproaches = 0
        """Force: descents repeated more slowly because the force rose in too few readings (all points)."""

    @property
    def done(self) -> bool:
        return self.phase == "done"

    @property
    def failed(self) -> bool:
        return self.phase == "failed"

    def start(self) -> None:
        """Begin with the first point."""
        self._go(0)

    # -- probe data ------------------------------------------------------------------------------
    def note_pose(self, stamp_ns: int, x_mm: float, y_mm: float, z_mm: float) -> None:
        """The arm's position at a time (the scanner's pose stream): probe samples are matched to it by stamp."""
        self._pose.add(stamp_ns, (x_mm, y_mm, z_mm))

    def on_heights(self, stamp_ns: int, h_mm: Sequence[float], valid: bool = True) -> None:
        """Air-float probe sample: SPS1..3 extensions (mm) below the face."""
        at = self._over_point_at(stamp_ns) if self.cfg.signal == "heights" and valid else None
        if at is None:
            return
        sps = statistics.fmean(h_mm[:3])
        if max(h_mm[:3]) - min(h_mm[:3]) > self.cfg.max_spread_mm or max(h_mm[:3]) >= self.cfg.stroke_mm - 0.05:
            # a sensor hangs over an edge (or sees nothing: the end of its stroke): this sample does not give the
            # surface here; a search stops there (something is under the ring: going on down could put the face on
            # the specimen's edge)
            if self.cfg.search and min(h_mm[:3]) < self.cfg.threshold:
                self._edge += 1
                if self._edge >= self.cfg.samples:
                    self._miss()
            return
        if sps < self.cfg.threshold:
            self._contact(at[2] - sps)

    def on_indenters(self, stamp_ns: int, displacement_mm: Sequence[float], valid: Sequence[bool]) -> None:
        """Camera probe sample: indenter displacements (mm)."""
        at = self._over_point_at(stamp_ns) if self.cfg.signal == "indenters" else None
        if at is None:
            return
        z = at[2]
        if self._tare is None:
            # tared on the first sample over the point (above the surface): the guides' friction can hold an
            # indenter a fraction of a millimetre in after the last press, and that offset is not contact here
            self._tare = tuple(displacement_mm)
            return
        moved = [(d - t, d) for d, t, ok in zip(displacement_mm, self._tare, valid, strict=False) if ok]
        if not moved:
            return
        rise, d = max(moved)
        if rise > 0.25 * self.cfg.threshold:
            # the fit goes through the indenter's own displacement, not the tared one: one held in by friction
            # slides back along the line of a free one (its spring and the sample), which ends where contact began
            self._rising.append((z, d))
        if rise > self.cfg.threshold:
            # the indenters' springs move about linearly with the press: back to where they began to move
            self._found = [self._zero_crossing(z, 1.0)] * self.cfg.samples
            self._contact(self._found[0])

    # -- driving ---------------------------------------------------------------------------------
    def step(self) -> None:
        """Advance: force contact, the end of a descent without contact, the arm at rest after a stop."""
        if self.phase in ("idle", "done", "failed"):
            return
        st = self.driver.state()
        prog = self.driver.progress()
        if prog.status in (MotionStatus.PROTECTIVE_STOP, MotionStatus.DISCONNECTED, MotionStatus.FAULT):
            self._fail(f"robot {prog.status.name.lower()} during the touch-off: {prog.message}")
            return
        if self.phase == "searching":
            if self.cfg.signal == "force" and self._over_point(st.pose[0], st.pose[1]):
                self._on_force(st.pose[2], abs(st.force_n[2]))
            if self.phase == "searching" and prog.status == MotionStatus.DONE:
                if self.cfg.search:
                    self._miss()
                    return
                x, y = self.points[self.index]
                self._fail(f"touch-off found no surface at ({x:g}, {y:g}) mm down to z {self.cfg.floor_z_mm:g} mm "
                           f"({self._signal_text()}): is the specimen under the region?")
            return
        if self.phase == "lifting" and prog.status == MotionStatus.DONE:
            self.phase = "done"
        if self.phase == "stopping" and math.hypot(*st.speed_mm_s[:3]) < 0.5 and prog.status != MotionStatus.MOVING:
            if self._again_from is not None:
                self._descend(self._again_from)
            else:
                self._go(self.index + 1)

    def _signal_text(self) -> str:
        c = self.cfg
        return {"heights": f"no SPS height under {c.threshold:g} mm", "indenters":
                f"no indenter moved {c.threshold:g} mm", "force": f"no force over {c.threshold:g} N"}[c.signal]

    def _on_force(self, z: float, f: float) -> None:
        if f <= 0.05 * self.cfg.threshold:
            self._free_z = z
            return
        self._rising.append((z, f))
        if f > self.cfg.threshold:
            z0 = contact_onset_z(self._rising, _FORCE_POWERS)
            if z0 is None and self._slower < _REAPPROACHES:
                self._reapproach()
                return
            self._found = [z if z0 is None else z0] * self.cfg.samples
            self._contact(self._found[0])

    def _reapproach(self) -> None:
        """Too few readings of the rise to fit where it began: stop, and once at rest back up to 1 mm over the last
        force-free height (or the start height) and descend again at half the speed."""
        self._slower += 1
        self.reapproaches += 1
        free = self._free_z
        self._again_from = self.cfg.start_z_mm if free is None else min(self.cfg.start_z_mm, free + 1.0)
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase = "stopping"

    def _zero_crossing(self, z_now: float, power: float) -> float:
        """Height where the signal began, s linear in the depth to the power ``power`` (else ``z_now``)."""
        z0 = contact_onset_z(self._rising, (power,))
        return z_now if z0 is None else z0

    def _over_point_at(self, stamp_ns: int) -> tuple[float, ...] | None:
        """The arm's (x, y, z) when a probe sample stamped ``stamp_ns`` was measured, if it was then over the point
        being searched; else None. Where the arm was then, not where it is when the sample is handled: on the wall
        clock a sample can be handled after the arm arrived though it was measured on the way, over the specimen,
        and a point whose ring hangs over the edge was taken for a touch (the search test through ur_rtde, once in
        a CI run)."""
        at = self._pose.at(stamp_ns, max_extrapolate_ns=50_000_000)
        return at if at is not None and self._over_point(at[0], at[1]) else None

    def _over_point(self, x_mm: float, y_mm: float) -> bool:
        """Searching, and (x, y) within _NEAR_MM of the point being searched."""
        if self.phase != "searching":
            return False
        x, y = self.points[self.index]
        return math.hypot(x_mm - x, y_mm - y) < _NEAR_MM

    def _contact(self, z_surface: float) -> None:
        self._found.append(z_surface)
        if len(self._found) < self.cfg.samples:
            return
        x, y = self.points[self.index]
        z = statistics.median(self._found[: self.cfg.samples])
        if z < self.cfg.floor_z_mm and self.cfg.search:
            self._miss()
            return
        if z < self.cfg.floor_z_mm:
            self._fail(f"touch-off found no specimen at ({x:g}, {y:g}) mm: the surface there is at z {z:.2f} mm, "
                       f"below the floor {self.cfg.floor_z_mm:g} mm (the table): is the specimen under the region?")
            return
        self.touches.append((x, y, z))
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase = "stopping"

    def _miss(self) -> None:
        self.misses.append(self.points[self.index])
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase = "stopping"

    def _go(self, index: int) -> None:
        self.index, self._found, self._rising, self._tare, self._edge = index, [], [], None, 0
        self._free_z, self._slower, self._again_from = None, 0, None
        if index >= len(self.points):
            x, y, z = self.driver.state().pose[:3]
            if self.cfg.start_z_mm - z < 0.5:  # contact came at the start height: no lift (a move of a few
                self.phase = "done"  # hundredths of a millimetre can end before ur_rtde sees it start)
                return
            self.driver.move_path([self._point(x, y, self.cfg.start_z_mm, self.cfg.transit_speed_mm_s)])
            self.phase = "lifting"
            return
        c = self.cfg
        x0, y0 = self.driver.state().pose[:2]
        x, y = self.points[index]
        self.driver.move_path([self._point(x0, y0, c.start_z_mm, c.transit_speed_mm_s),
                               self._point(x, y, c.start_z_mm, c.transit_speed_mm_s),
                               self._point(x, y, c.floor_z_mm, c.search_speed_mm_s)])
        self.phase = "searching"

    def _descend(self, top: float) -> None:
        """Over the same point again: up to ``top``, then down at the search speed halved per re-approach."""
        c = self.cfg
        x, y = self.points[self.index]
        self._found, self._rising, self._free_z, self._again_from = [], [], None, None
        self.driver.move_path([self._point(x, y, top, c.transit_speed_mm_s),
                               self._point(x, y, c.floor_z_mm, c.search_speed_mm_s / 2 ** self._slower)])
        self.phase = "searching"

    def _point(self, x: float, y: float, z: float, speed: float) -> PathPoint:
        return PathPoint(x, y, z, speed, self.cfg.accel_mm_s2)

    def _fail(self, why: str) -> None:
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase, self.error = "failed", why


_DEFAULT_THRESHOLD = {"heights": 9.0, "indenters": 0.3, "force": 0.5}


class SpecimenPlanner:
    """The scanner's specimen: its region (given, or the measured footprint less a margin), the prior surface
    (the measured thickness), the touch-off that finds the real one, and the raster's surface after it.

    Everything that can be refused is refused in the constructor, before any motion: a region or a specimen
    height the workspace box cannot hold raises ``palpa.ParamError`` naming the box and the extent.
    """

    def __init__(self, node: RobotScanner) -> None:
        self.node = node
        self.search_box: tuple[float, ...] | None = None
        p = node.params
        box = p.workspace_mm
        geo = None
        if p.geometry:
            try:
                geo = load_geometry(p.geometry)
            except GeometryError as exc:
                raise palpa.ParamError(f"{node.name}: geometry: {exc}") from None
        footprint = geo.footprint_mm() if geo is not None else None
        try:
            if p.region_mm:
                if len(p.region_mm) != 4:
                    raise palpa.ParamError(f"{node.name}: region_mm needs x0, y0, x1, y1, got {p.region_mm}")
                self.region = (float(p.region_mm[0]), float(p.region_mm[1]), float(p.region_mm[2]),
                               float(p.region_mm[3]))
                what = "the scan region (region_mm)"
            elif p.search_box_mm:
                self.search_box = _search_box(node.name, p.search_box_mm, p.touchoff, box)
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
                raise palpa.ParamError(f"{node.name}: no scan region: give region_mm (x0, y0, x1, y1 mm), a "
                                       "search_box_mm to find the specimen in, or a geometry file with its footprint")
            top = geo.top_mm() if geo is not None else None
            clearance = p.search_clearance_mm if p.touchoff != "off" else p.retract_clearance_mm
            check_fits(self.region, box, top_mm=top, clearance_mm=clearance, what=what)
        except (SpecimenDoesNotFit, ValueError) as exc:
            raise palpa.ParamError(f"{node.name}: refusing the specimen before any motion: {exc}") from None
        self.prior_top = top
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
                self.touch = TouchOff(node.driver, search_points(self.region, p.search_step_mm), cfg)
                return
            i = p.touch_inset_mm
            x0, y0, x1, y1 = self.region
            inner = (x0 + i, y0 + i, x1 - i, y1 - i) if x1 - x0 > 2 * i and y1 - y0 > 2 * i else self.region
            self.touch = TouchOff(node.driver, touch_points(inner, p.touch_grid), cfg)

    def plan_heights(self) -> dict[str, object]:
        """Keyword arguments of the raster functions for the heights: flat, or over the surface."""
        p = self.node.params
        if self.surface is None:
            return {"contact_z_mm": p.contact_z_mm}
        if p.mode == "sweep":
            return {"contact_z_mm": p.working_offset_mm, "surface": self.surface}
        return {"contact_z_mm": 0.0, "surface": self.surface}

    def plan_z(self) -> Callable[[float, float], float] | None:
        """A sweep's planned face height at (x, y) over the found surface (None: no surface)."""
        surface, offset = self.surface, self.node.params.working_offset_mm
        if surface is None:
            return None
        return lambda x, y: surface.z(x, y) + offset

    def press_depth_mm(self) -> float:
        """Indent depth: the set depth, but never more than ``max_press_fraction`` of the thinnest found point nor
        closer than 0.2 mm to the workspace box's floor."""
        p = self.node.params
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
            sb, p = self.search_box, self.node.params
            self.region = region_from_touches(self.touch.touches, p.edge_margin_mm, (sb[0], sb[1], sb[3], sb[4]))
            xs, ys = [t[0] for t in self.touch.touches], [t[1] for t in self.touch.touches]
            found = (f"search: the specimen under {len(xs)} of {len(xs) + len(self.touch.misses)} points, extent x "
                     f"{min(xs):g}..{max(xs):g}, y {min(ys):g}..{max(ys):g} mm; region x {self.region[0]:g}.."
                     f"{self.region[2]:g}, y {self.region[1]:g}..{self.region[3]:g} mm; ")
        fit = fit_surface(self.touch.touches)
        self.surface = fit
        zs = [z for _, _, z in self.touch.touches]
        slower = (f"; {self.touch.reapproaches} descents repeated more slowly (the force rose in too few readings)"
                  if self.touch.reapproaches else "")
        return (f"{found}touch-off: {len(zs)} points, surface {min(zs):.2f}..{max(zs):.2f} mm, {fit.model} fit "
                f"(rms {fit.rms_mm:.3f} mm){slower}")


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
