"""Holds the probe still: publishes a fixed ``robot/pose`` (a bench fixture, or a parked arm in simulation)."""

from __future__ import annotations

import palpa
from messages import RobotPose

__all__ = ["StaticPose"]


class StaticPose(palpa.Node):
    """Publishes the configured TCP pose (phantom frame, mm) at ``rate_hz``."""

    class Params(palpa.Params):
        x_mm: float = 30.0
        y_mm: float = 30.0
        z_mm: float = 21.0
        rate_hz: float = 250.0

    params: Params

    def setup(self) -> None:
        self.pub = self.publisher("robot/pose", RobotPose)
        self.timer(1.0 / self.params.rate_hz, self.tick, first_in_s=0.0)

    def tick(self) -> None:
        p = self.params
        self.pub.publish(RobotPose(stamp_ns=self.clock.now_ns(), x_mm=p.x_mm, y_mm=p.y_mm, z_mm=p.z_mm))


if __name__ == "__main__":
    palpa.run_node(StaticPose)
