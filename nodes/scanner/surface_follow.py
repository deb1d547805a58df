"""The scanner's surface following (``models.following``): while the probe slides along a sweep line, its own
heights correct the line's height, and the rest of the line goes out again, raised or lowered, through the same
checks as any plan.

How a correction reaches the arm: the scanner re-sends the rest of the current line (the plan's waypoints from the
one being approached, every contact height plus the offset) as a new path, at most every ``min_interval_s`` and
only once the offset moved ``deadband_mm`` from the one sent. Both drivers take a new path while moving (the arm
decelerates out of the old one and sets off on the new: a short slow-down), and each re-sent path is checked against the workspace box and the
speed and acceleration caps before it goes (``RobotScanner.check_path``), so following cannot leave the box: the
offset is also bounded so that the line stays inside it. Stale probe data stops the arm as before (the scanner's
watchdog); without fresh samples the offset does not move.

The probe's samples reach the scanner late (the fibre reader drains its device in batches: up to 0.1 s), and the arm
reaches a re-sent offset later still. An integral law on the clearance error alone would then correct again what it
has already corrected, and oscillate (±0.2 mm on a flat specimen at 20 mm/s). So each sample is read against where
the face really was when it was taken (the arm's pose at the sample's stamp, less the plan's height there): its
error says which offset would have been right then, and the law moves the current offset towards that, which no
delay can destabilise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from models.following import FollowConfig, clearance_error, follow_step, is_slide, shift_line
from models.raster import Waypoint
from models.timeseries import StampedBuffer

__all__ = ["LineFollower"]

_MAX_DT_S = 0.05  # a gap in the samples longer than this is not integrated over


class LineFollower:
    """Offset of the current sweep line from its plan, driven by ``probe/heights`` while sliding."""

    def __init__(self, cfg: FollowConfig, box_z_mm: tuple[float, float], *, deadband_mm: float = 0.1,
                 min_interval_s: float = 0.1) -> None:
        self.cfg, self.box_z = cfg, box_z_mm
        self.deadband_mm, self.min_interval_ns = deadband_mm, int(min_interval_s * 1e9)
        self.line = -1
        self.offset_mm = 0.0
        self.sent_mm = 0.0
        self.sliding = False
        self.limits = (-math.inf, math.inf)
        self.resends = 0
        self.plan_z: Callable[[float, float], float] | None = None
        self._pose = StampedBuffer(max_gap_ns=200_000_000)
        self.largest_mm = 0.0
        """The largest offset sent so far (mm, either sign): how wrong the fitted surface was under the lines."""
        self._last_stamp: int | None = None
        self._sent_ns = 0

    def note_pose(self, stamp_ns: int, x_mm: float, y_mm: float, z_mm: float) -> None:
        """The arm's pose at a time (the scanner's pose stream): samples are read against it by stamp."""
        self._pose.add(stamp_ns, (x_mm, y_mm, z_mm))

    def start_line(self, waypoints: Sequence[Waypoint], line: int,
                   plan_z: Callable[[float, float], float] | None = None) -> None:
        """A new line from its plan, bounded so that every contact height of it stays in the box. The next line of
        a boustrophedon starts beside where the last one ended: it starts at that offset (the first at 0)."""
        zs = [w.z_mm for w in waypoints if w.kind == "contact" and w.line == line]
        self.plan_z = plan_z
        self.limits = (self.box_z[0] - min(zs), self.box_z[1] - max(zs)) if zs else (0.0, 0.0)
        carried = self.offset_mm if line == self.line + 1 else 0.0
        carried = max(self.limits[0], min(self.limits[1], carried)) if self.limits[0] <= self.limits[1] else 0.0
        self.line, self.offset_mm, self.sent_mm, self.sliding, self._last_stamp = line, carried, carried, False, None

    def track(self, path: Sequence[Waypoint], index: int) -> None:
        """The arm is heading for ``path[index]``: following runs only while it slides along the line."""
        self.sliding = is_slide(path, index) and path[index].line == self.line
        if not self.sliding:
            self._last_stamp = None

    def on_heights(self, stamp_ns: int, h_mm: Sequence[float], valid: bool) -> None:
        """One probe sample: integrate the clearance error (not while off the line, nor an unusable sample)."""
        if not self.sliding or not valid:
            return
        error = clearance_error(h_mm, self.cfg)
        pose = self._pose.at(stamp_ns, max_extrapolate_ns=50_000_000)
        if error is None or pose is None:
            return
        if self.plan_z is not None:  # where the face was against the plan then, not the offset asked since
            error += self.offset_mm - (pose[2] - self.plan_z(pose[0], pose[1]))
        if self._last_stamp is not None and stamp_ns > self._last_stamp:
            dt = min((stamp_ns - self._last_stamp) / 1e9, _MAX_DT_S)
            self.offset_mm = follow_step(self.offset_mm, error, dt, self.cfg, self.limits)
        self._last_stamp = stamp_ns

    def due(self, now_ns: int) -> bool:
        """Whether the rest of the line should go out again with the new offset."""
        return (self.sliding and abs(self.offset_mm - self.sent_mm) >= self.deadband_mm
                and now_ns - self._sent_ns >= self.min_interval_ns)

    def shifted(self, waypoints: Sequence[Waypoint]) -> tuple[Waypoint, ...]:
        """``waypoints`` with the current line's contact heights at the current offset."""
        return shift_line(waypoints, self.line, self.offset_mm)

    def sent(self, now_ns: int) -> None:
        self.sent_mm, self._sent_ns = self.offset_mm, now_ns
        if abs(self.offset_mm) > abs(self.largest_mm):
            self.largest_mm = self.offset_mm
        self.resends += 1
