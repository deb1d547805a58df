"""Simulation time for a whole graph: a node that publishes ``ClockTick`` on ``_palpa/clock``.

Nodes started with ``--sim-clock`` (or ``PALPA_SIM_CLOCK=1`` in their environment) take their time from it, so a
simulated graph can run ``time_scale`` times faster than real time and still stamp, time out and rate-limit
consistently. ``palpa play --clock`` drives the same topic from a recording.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from palpa.clock import SystemClock
from palpa.node import Node
from palpa.params import Params
from palpa.runner import run_node
from palpa.runtime_msgs import CLOCK_TOPIC, ClockTick

__all__ = ["ClockSource"]


class ClockSource(Node):
    """Publishes simulation time: ``start + time_scale * (wall time since start)`` at ``rate_hz`` wall ticks."""

    class Params(Params):
        time_scale: float = 1.0
        """Simulated seconds per wall-clock second (> 0)."""
        rate_hz: float = 1000.0
        """Ticks per wall-clock second: the time resolution timers in sim-clock nodes get."""

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | Params | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # the source of time cannot follow itself
        kwargs.setdefault("clock", SystemClock())
        super().__init__(name, params, **kwargs)

    def setup(self) -> None:
        if self.params.time_scale <= 0 or self.params.rate_hz <= 0:
            raise ValueError("time_scale and rate_hz must be > 0")
        self._pub = self.publisher(CLOCK_TOPIC, ClockTick, batch=1)
        self._wall0 = time.monotonic_ns()
        self._sim0 = time.time_ns()
        self.timer(1.0 / self.params.rate_hz, self._tick, first_in_s=0.0)

    def sim_now_ns(self) -> int:
        return self._sim0 + int((time.monotonic_ns() - self._wall0) * self.params.time_scale)

    def _tick(self) -> None:
        self._pub.publish(ClockTick(sim_ns=self.sim_now_ns()))


if __name__ == "__main__":
    run_node(ClockSource)
