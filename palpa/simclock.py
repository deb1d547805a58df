"""Simulation time for a whole graph: a node that publishes ``ClockTick`` on ``_palpa/clock``.

Nodes started with ``--sim-clock`` (or ``PALPA_SIM_CLOCK=1`` in their environment) take their time from it, so a
simulated graph can run ``time_scale`` times faster than real time and still stamp, time out and rate-limit
consistently. ``palpa play --clock`` drives the same topic from a recording.

Lockstep: every sim-clock node acknowledges the time it has handled (``_palpa/clock_ack``); the source never runs
more than ``max_lead_s`` of simulated time ahead of the slowest node heard in the last ``participant_timeout_s``.
On an overloaded machine simulated time therefore slows down — ``time_scale`` is a ceiling — instead of nodes
falling behind and seeing each other's data go stale.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from palpa.clock import SystemClock
from palpa.node import Node
from palpa.params import Params as ParamsBase
from palpa.runner import run_node
from palpa.runtime_msgs import CLOCK_ACK_TOPIC, CLOCK_TOPIC, ClockAck, ClockTick

__all__ = ["ClockSource"]


class ClockSource(Node):
    """Publishes simulation time: ``start + time_scale * (wall time since start)`` at ``rate_hz`` wall ticks."""

    class Params(ParamsBase):
        time_scale: float = 1.0
        """Simulated seconds per wall-clock second (> 0)."""
        rate_hz: float = 1000.0
        """Ticks per wall-clock second: the time resolution timers in sim-clock nodes get."""
        max_lead_s: float = 0.02
        """Simulated seconds the clock may run ahead of the slowest acknowledging node (0: no lockstep)."""
        participant_timeout_s: float = 2.0
        """A node not heard for this long (wall clock) no longer holds the clock back (it died or stopped)."""

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | Params | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # the source of time cannot follow itself
        kwargs.setdefault("clock", SystemClock())
        super().__init__(name, params, **kwargs)

    def setup(self) -> None:
        if self.params.time_scale <= 0 or self.params.rate_hz <= 0:
            raise ValueError("time_scale and rate_hz must be > 0")
        self._pub = self.publisher(CLOCK_TOPIC, ClockTick, batch=1)
        self._wall = time.monotonic_ns()
        self._sim = time.time_ns()
        self._acks: dict[str, tuple[int, int]] = {}
        """node -> (acknowledged sim ns, wall monotonic ns when heard)"""
        self.held_ns = 0
        """Simulated time withheld so far because a node lagged."""
        self._dropped: set[str] = set()
        if self.params.max_lead_s > 0:
            self.subscribe(CLOCK_ACK_TOPIC, self._on_ack)
        self.timer(1.0 / self.params.rate_hz, self._tick, first_in_s=0.0)

    def _on_ack(self, ack: ClockAck) -> None:
        self._acks[ack.node] = (ack.sim_ns, time.monotonic_ns())
        self._dropped.discard(ack.node)

    def sim_now_ns(self) -> int:
        """Advance simulated time by the wall time since the last call (scaled), held back to the lockstep limit."""
        wall = time.monotonic_ns()
        proposed = self._sim + int((wall - self._wall) * self.params.time_scale)
        self._wall = wall
        cutoff = wall - int(self.params.participant_timeout_s * 1e9)
        live = [sim for sim, heard in self._acks.values() if heard >= cutoff]
        if len(live) < len(self._acks) - len(self._dropped):
            for node, (_, heard) in self._acks.items():
                if heard < cutoff and node not in self._dropped:
                    self._dropped.add(node)  # said once: a node that stays away is not news every tick
                    self.log.warning("%s not heard for %.1f s (wall clock): it no longer holds simulated time back",
                                     node, self.params.participant_timeout_s)
        if live and self.params.max_lead_s > 0:
            limit = min(live) + int(self.params.max_lead_s * 1e9)
            if proposed > limit:
                proposed = max(limit, self._sim)
        self._sim = proposed
        return proposed

    def _tick(self) -> None:
        self._pub.publish(ClockTick(sim_ns=self.sim_now_ns()))


if __name__ == "__main__":
    run_node(ClockSource)
