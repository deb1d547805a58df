"""Linear stage: the camera paper's motorised linear module (Fig. 4) as a sim fixture on ``robot/pose``.

The probe is held at (x, y) over the sample and pressed along −z into it and back, ``cycles`` times:

    settle at the top -> down at ``speed`` to ``depth`` below the surface -> hold (``ramp_hold``) -> up -> dwell

The top is ``start_gap_mm`` above the surface (no contact: the camera tracker takes its zero reference there
while settling). The surface height is the phantom's at (x, y) when ``phantom`` is given, else ``surface_z_mm``.
Poses (the probe's centre indenter tip at rest, phantom frame, mm) go out at ``rate_hz`` on ``robot/pose``;
progress on ``robot/scan_status`` (one "line" per press cycle). With ``exit_when_done`` the node exits 0 after
the last cycle, so a launch can make it ``required``.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import palpa
from messages import RobotPose, ScanStatus
from nodes.common import phantom_from_param
from palpa.node.node import RawMessage

__all__ = ["LinearStage", "StageProfile", "StageSample"]


class StageSample(NamedTuple):
    """Where the stage is at one time: z (mm), signed speed (mm/s, negative = pressing), phase, cycle (0-based)."""

    z_mm: float
    speed_mm_s: float
    phase: str
    """``settle``, ``press``, ``hold``, ``release``, ``dwell``, ``done``."""
    cycle: int


class StageProfile(NamedTuple):
    """A press profile: heights (mm), speed (mm/s), times (s) and cycle count (0 = forever)."""

    top_z_mm: float
    bottom_z_mm: float
    speed_mm_s: float
    hold_s: float
    settle_s: float
    dwell_s: float
    cycles: int

    @property
    def cycle_s(self) -> float:
        """Duration of one press cycle (s)."""
        return 2 * (self.top_z_mm - self.bottom_z_mm) / self.speed_mm_s + self.hold_s + self.dwell_s

    def at(self, t_s: float) -> StageSample:
        """Stage position ``t_s`` seconds after start (a pure function of time)."""
        if t_s < self.settle_s:
            return StageSample(self.top_z_mm, 0.0, "settle", 0)
        move_s = (self.top_z_mm - self.bottom_z_mm) / self.speed_mm_s
        cycle, u = divmod(t_s - self.settle_s, self.cycle_s)
        if self.cycles and cycle >= self.cycles:
            return StageSample(self.top_z_mm, 0.0, "done", self.cycles - 1)
        c = int(cycle)
        if u < move_s:
            return StageSample(self.top_z_mm - self.speed_mm_s * u, -self.speed_mm_s, "press", c)
        u -= move_s
        if u < self.hold_s:
            return StageSample(self.bottom_z_mm, 0.0, "hold", c)
        u -= self.hold_s
        if u < move_s:
            return StageSample(self.bottom_z_mm + self.speed_mm_s * u, self.speed_mm_s, "release", c)
        return StageSample(self.top_z_mm, 0.0, "dwell", c)


class LinearStage(palpa.Node):
    """Presses the probe into the sample along z with a triangle or ramp-hold profile."""

    class Params(palpa.Params):
        x_mm: float = 20.0
        y_mm: float = 20.0
        phantom: palpa.InputPath = ""
        """Phantom file to take the surface height at (x, y) from; empty: ``surface_z_mm``."""
        surface_z_mm: float = 30.0
        start_gap_mm: palpa.NonNegative = 4.0
        """Clearance above the surface (at the probe centre) at the top of each cycle. On an inclined sample the
        surface under an outer indenter is higher, by 8 mm x tan(angle): 4 mm keeps all four clear up to 25°."""
        depth_mm: palpa.Positive = 8.0
        """Press depth below the surface at the probe centre."""
        speed_mm_s: palpa.Positive = 2.0
        profile: Literal["triangle", "ramp_hold"] = "ramp_hold"
        hold_s: palpa.NonNegative = 2.0
        """Time held at depth (ramp_hold)."""
        settle_s: palpa.NonNegative = 1.5
        """Time at the top before the first press (the camera's zero reference is taken then)."""
        dwell_s: palpa.NonNegative = 0.5
        """Time at the top between cycles."""
        cycles: int = 1
        """Press cycles; 0: forever."""
        exit_when_done: bool = False
        rate_hz: palpa.Positive = 100.0
        start_after_topic: str = ""
        """Hold at the top until a message arrives on this topic, then start the profile (e.g. ``camera/indenters``,
        which the camera tracker publishes only once it has its zero reference). Empty: start at once."""

    params: Params

    def setup(self) -> None:
        p = self.params
        problems = [name for name, ok in (
            ("speed_mm_s", p.speed_mm_s > 0), ("rate_hz", p.rate_hz > 0), ("start_gap_mm", p.start_gap_mm >= 0),
            ("depth_mm", p.depth_mm + p.start_gap_mm > 0), ("hold_s", p.hold_s >= 0), ("settle_s", p.settle_s >= 0),
            ("dwell_s", p.dwell_s >= 0), ("cycles", p.cycles >= 0)) if not ok]
        if problems:
            raise palpa.ParamError(f"node {self.name!r}: invalid {', '.join(problems)} (times and gaps >= 0, "
                                   f"speed and rate > 0, some travel)")
        if p.phantom:
            surface = float(phantom_from_param(p.phantom, self.name).surface_z(p.x_mm, p.y_mm))
            if not math.isfinite(surface) or surface <= 0:
                raise palpa.ParamError(f"node {self.name!r}: ({p.x_mm}, {p.y_mm}) mm is off the phantom {p.phantom}")
        else:
            surface = p.surface_z_mm
        self.surface_z_mm = surface
        self.profile = StageProfile(
            top_z_mm=surface + p.start_gap_mm, bottom_z_mm=surface - p.depth_mm, speed_mm_s=p.speed_mm_s,
            hold_s=p.hold_s if p.profile == "ramp_hold" else 0.0, settle_s=p.settle_s, dwell_s=p.dwell_s,
            cycles=p.cycles,
        )
        self.pose_pub = self.publisher("robot/pose", RobotPose)
        self.status_pub = self.publisher("robot/scan_status", ScanStatus)
        self._t0: int | None = None if p.start_after_topic else self.clock.now_ns()
        self.last = self.profile.at(0.0)
        if p.start_after_topic:
            self.subscribe_raw(self.resolve(p.start_after_topic), self._on_start_topic)
            self.log.info("holding at the top until %s publishes", self.resolve(p.start_after_topic))
        self.timer(1.0 / p.rate_hz, self.tick, first_in_s=0.0)

    def _on_start_topic(self, raw: RawMessage) -> None:
        # subscribe_raw matches by prefix; the topic must be exactly the one asked for.
        if self._t0 is None and raw.topic == self.resolve(self.params.start_after_topic):
            self._t0 = self.clock.now_ns()
            self.log.info("%s is publishing: starting the press profile", raw.topic)

    def tick(self) -> None:
        p = self.params
        now = self.clock.now_ns()
        t = 0.0 if self._t0 is None else (now - self._t0) / 1e9
        s = self.profile.at(t)
        self.pose_pub.publish(RobotPose(stamp_ns=now, x_mm=p.x_mm, y_mm=p.y_mm, z_mm=s.z_mm, speed_mm_s=s.speed_mm_s))
        changed = s.phase != self.last.phase
        self.last = s
        if changed or int(t * p.rate_hz) % max(1, int(p.rate_hz)) == 0:
            self._publish_status(t, s)
        if s.phase == "done" and p.exit_when_done:
            self.log.info("%d press cycle(s) done", p.cycles)
            self.request_shutdown(0)

    def _publish_status(self, t: float, s: StageSample) -> None:
        p = self.params
        total = p.settle_s + p.cycles * self.profile.cycle_s
        progress = 1.0 if s.phase == "done" else (min(1.0, t / total) if p.cycles else 0.0)
        self.status_pub.publish(ScanStatus(
            stamp_ns=self.clock.now_ns(), state="done" if s.phase == "done" else "scanning", line=s.cycle,
            lines=p.cycles, progress=progress, eta_s=max(0.0, total - t) if p.cycles else 0.0, message=s.phase,
        ))


if __name__ == "__main__":
    palpa.run_node(LinearStage)
