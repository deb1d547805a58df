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
* ``force`` -- the arm's TCP force (ur_rtde's ``actual_TCP_force``). Over each point the arm first rests at the
  start height and reads the force's zero and spread there (a robot's sensor is offset by newtons until zeroed,
  and noisy); a ``threshold`` under 6 sigma of that spread is refused, naming it (a UR's built-in sensor, sigma
  ~1 N, cannot see soft tissue: touch off with the probe's own signal). Contact is |Fz - zero| above
  ``threshold`` (N); the surface is the height where the force began: the readings from 3 sigma to ``threshold``
  are fitted with F = (k (z0 - z))^p (:func:`models.surface.contact_onset_z`), p in 1..2.5 around Hertz's 1.5
  (a thin layer stiffens past it, which put a 6 mm dome's surface 0.1 mm low; noisy readings cannot pull p far).
  The force is read when :meth:`step` runs; if the rise went by in fewer than 16 readings (a descent too fast for a
  busy PC's steps), the arm backs up to 1 mm over the last force-free height and descends again at half the
  speed, up to three times (``reapproaches`` counts them); a rise still read fewer than 4 times then fails the
  touch-off, naming the point, rather than take the depth it was seen at for the surface.

With a table point first (``table_points``, the scanner's ``table_point_mm``) the SPS read the table's height
beside the specimen before the specimen's points (``table_touches``; docs/robot.md, "Table touch").

A descent that reaches the floor without contact is an error naming the point (nothing under it); in a search for
the specimen (``search``, the scanner's ``search_box_mm``) it is a miss, and so is a ring half over an edge. The driver
is any :class:`nodes.drivers.robot.RobotDriver`; the scanner feeds probe data and calls :meth:`step` from its
timer. Pure logic apart from the driver: testable on the sim driver with a mock clock, and on the UR emulator.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from models.surface import contact_onset_z
from models.timeseries import StampedBuffer
from nodes.drivers.robot import MotionStatus, PathPoint, RobotDriver

__all__ = ["TouchOff", "TouchOffConfig"]

Signal = Literal["heights", "indenters", "force"]
_NEAR_MM = 0.5
_FORCE_POWERS = tuple(1.0 + 0.05 * k for k in range(31))  # a contact law's exponent: 1 (a spring) .. 2.5
_REAPPROACHES = 3
_MIN_RISE = 16  # force: readings of the rise wanted for the fit (fewer, noisy, let the exponent wander)
_TARE_READINGS = 20  # force: readings at rest for the zero and the spread (10 put sigma 30 % low one time in 10)
_NOISE_MARGIN = 6.0  # force: the threshold must clear the noise at rest by this many sigma (the fit starts at 3)
# the exponent's prior: Hertz's 1.5 unless the readings say otherwise, and noisy ones cannot pull it far. On
# dome_6_3 (tests/test_touchoff_force.py) a wrist sensor's 3 mN noise put the surface -0.19..+0.19 mm off with
# sigma 0.25 and 8 readings, -0.09..+0.07 with 0.15 and 16; without noise -0.06..+0.03 mm
_FORCE_PRIOR = (1.5, 0.15)


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
    table_points: int = 0
    """The first this many points are bare table beside the specimen (the scanner's ``table_point_mm``): their
    surface is the table's, below the floor (the SPS read it from ``threshold`` above: the face never comes near
    it), kept in ``table_touches``; nothing found there is an error, searching or not."""


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
        self.table_touches: list[tuple[float, float, float]] = []
        """(x, y, z_table) at the table points (``config.table_points``)."""
        self.misses: list[tuple[float, float]] = []
        self._edge = 0  # heights, search: samples with the SPS ring half over an edge at this point
        self.index = 0
        self.phase: Literal["idle", "taring", "searching", "stopping", "lifting", "done", "failed"] = "idle"
        self.error = ""
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self._found: list[float] = []
        self._rising: list[tuple[float, float]] = []  # (z, signal) since the contact signal began to rise
        self._tare: tuple[float, ...] | None = None  # indenters: their displacements when the search here began
        self._free_z: float | None = None  # force: the last height over this point with no force yet
        self._slower = 0  # force: re-approaches at this point (each at half the last descent's speed)
        self._again_from: float | None = None  # force: once stopped, descend again from this height
        self._stale_below: float | None = None  # force: after a stop, readings count once the arm rises past this
        self.reapproaches = 0
        """Force: descents repeated more slowly because the force rose in too few readings (all points)."""
        self._at_rest: list[float] = []  # force: distinct readings at the start height over this point
        self._rest_steps = 0
        self.force_zero_n = 0.0
        """Force: the reading at rest over the last point (the sensor's offset there), subtracted from the rest."""
        self.force_noise_n = 0.0
        """Force: the readings' spread (sigma, N) at rest over the last point."""

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
            if (self.cfg.search or self.index < self.cfg.table_points) and min(h_mm[:3]) < self.cfg.threshold:
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
        if self.phase == "taring":
            if prog.status != MotionStatus.MOVING and math.hypot(*st.speed_mm_s[:3]) < 0.5:
                self._tare_force(st.force_n[2])
            return
        if self.phase == "searching":
            if self.cfg.signal == "force" and self._over_point(st.pose[0], st.pose[1]):
                if self._stale_below is not None and (st.pose[2] > self._stale_below + 0.05 or prog.index >= 1):
                    self._stale_below = None  # the arm has left where it stopped: readings from now on are new
                if self._stale_below is None:
                    self._on_force(st.pose[2], abs(st.force_n[2] - self.force_zero_n))
            if self.phase == "searching" and prog.status == MotionStatus.DONE:
                if self.cfg.search or self.index < self.cfg.table_points:
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

    def _tare_force(self, fz: float) -> None:
        """At rest over the point at the start height, in the air: the sensor's zero and noise here. A threshold
        the noise would cross is refused, naming what would do."""
        self._rest_steps += 1
        if not self._at_rest or fz != self._at_rest[-1]:  # a new sample (the same one read twice: no spread)
            self._at_rest.append(fz)
        if len(self._at_rest) < _TARE_READINGS and self._rest_steps < 5 * _TARE_READINGS:
            return
        self.force_zero_n = statistics.fmean(self._at_rest)
        self.force_noise_n = statistics.stdev(self._at_rest) if len(self._at_rest) > 1 else 0.0
        c = self.cfg
        if c.threshold < _NOISE_MARGIN * self.force_noise_n:
            x, y = self.points[self.index]
            self._fail(f"touch-off by force at ({x:g}, {y:g}) mm: the force reads with a spread of "
                       f"{self.force_noise_n:.3f} N at rest ({len(self._at_rest)} readings), so a {c.threshold:g} N "
                       f"threshold would be crossed by noise; it needs at least {_NOISE_MARGIN * self.force_noise_n:.2f} "
                       "N, which a soft specimen may not push back before the table: touch off with the probe's own "
                       "signal (touchoff: heights or indenters) or a finer force sensor")
            return
        self._descend(c.start_z_mm, at_top=True)

    def _on_force(self, z: float, f: float) -> None:
        if f <= max(0.05 * self.cfg.threshold, 3.0 * self.force_noise_n):  # the rise is fitted above the noise
            # back under it: what rose before was noise (a contact's force does not fall while the arm descends)
            self._free_z, self._rising = z, []
            return
        if self._rising and self._rising[-1] == (z, f):
            return  # the same package read again (the driver's stream behind the steps): no new reading
        self._rising.append((z, f))
        if f > self.cfg.threshold:
            z0 = contact_onset_z(self._rising, _FORCE_POWERS, noise=self.force_noise_n, prior=_FORCE_PRIOR)
            if (z0 is None or len(self._rising) < _MIN_RISE) and self._slower < _REAPPROACHES:
                self._reapproach()
                return
            if z0 is None:  # the depth where the threshold was crossed is no surface: 1-2 mm into soft tissue
                x, y = self.points[self.index]
                self._fail(f"touch-off by force at ({x:g}, {y:g}) mm: the force rose past {self.cfg.threshold:g} N in "
                           f"{len(self._rising)} readings even at 1/{2 ** self._slower} of the search speed, too few "
                           "to find where it began: is step() called often enough (the node's timer)?")
                return
            self._found = [z0] * self.cfg.samples
            self._contact(self._found[0])

    def _reapproach(self) -> None:
        """Too few readings of the rise to fit where it began well: stop, and once at rest back up to 1 mm over the last
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
        if self.index < self.cfg.table_points:
            self.table_touches.append((x, y, z))
            self.driver.stop(self.cfg.accel_mm_s2)
            self.phase = "stopping"
            return
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
        if self.index < self.cfg.table_points:
            x, y = self.points[self.index]
            self._fail(f"the table touch at ({x:g}, {y:g}) mm found no bare table ({self._signal_text()}, or the SPS "
                       "ring half over an edge): is table_point_mm beside the specimen, on the table?")
            return
        self.misses.append(self.points[self.index])
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase = "stopping"

    def _go(self, index: int) -> None:
        self.index, self._found, self._rising, self._tare, self._edge = index, [], [], None, 0
        self._free_z, self._slower, self._again_from, self._stale_below = None, 0, None, None
        self._at_rest, self._rest_steps = [], 0
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
        if c.signal == "force":  # first at rest over the point, to read the force's zero and noise there
            self.driver.move_path([self._point(x0, y0, c.start_z_mm, c.transit_speed_mm_s),
                                   self._point(x, y, c.start_z_mm, c.transit_speed_mm_s)])
            self.phase = "taring"
            return
        self.driver.move_path([self._point(x0, y0, c.start_z_mm, c.transit_speed_mm_s),
                               self._point(x, y, c.start_z_mm, c.transit_speed_mm_s),
                               self._point(x, y, c.floor_z_mm, c.search_speed_mm_s)])
        self.phase = "searching"

    def _descend(self, top: float, *, at_top: bool = False) -> None:
        """Over the same point again: up to ``top`` (unless ``at_top``: the path there has ended), then down at the
        search speed halved per re-approach."""
        c = self.cfg
        x, y = self.points[self.index]
        self._found, self._rising, self._free_z, self._again_from = [], [], None, None
        down = self._point(x, y, c.floor_z_mm, c.search_speed_mm_s / 2 ** self._slower)
        # a stream behind its reader still gives the stopped arm's readings, deep in the tissue, after the new path
        # was sent: they count once one shows the arm above where it stopped, or the controller past the top
        self._stale_below = None if at_top else self.driver.state().pose[2]
        if at_top:  # not judged from the pose, which a stream behind its reader can give from before the stop
            self.driver.move_path([down])
        else:
            self.driver.move_path([self._point(x, y, top, c.transit_speed_mm_s), down])
        self.phase = "searching"

    def _point(self, x: float, y: float, z: float, speed: float) -> PathPoint:
        return PathPoint(x, y, z, speed, self.cfg.accel_mm_s2)

    def _fail(self, why: str) -> None:
        self.driver.stop(self.cfg.accel_mm_s2)
        self.phase, self.error = "failed", why
