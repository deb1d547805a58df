"""Scan progress by path length: which line, what fraction of the planned path is behind, and the ETA."""

from __future__ import annotations

import math
from collections.abc import Sequence

from models.raster import Waypoint

__all__ = ["PathProgressMeter"]


class PathProgressMeter:
    """Progress along a waypoint path given the index of the waypoint being approached and the TCP position."""

    def __init__(self, waypoints: Sequence[Waypoint], duration_s: float) -> None:
        self._w = list(waypoints)
        self._cum = [0.0]
        for a, b in zip(self._w, self._w[1:], strict=False):
            self._cum.append(self._cum[-1] + math.dist((a.x_mm, a.y_mm, a.z_mm), (b.x_mm, b.y_mm, b.z_mm)))
        self._total = self._cum[-1] or 1.0
        self._duration = duration_s
        self.progress = 0.0
        self.line = 0

    def update(self, target_index: int, tcp_mm: Sequence[float]) -> None:
        """``target_index``: the waypoint the arm is moving towards (or has reached)."""
        i = min(max(target_index, 0), len(self._w) - 1)
        done = self._cum[i - 1] if i > 0 else 0.0
        if i > 0:
            a, _b = self._w[i - 1], self._w[i]
            seg = self._cum[i] - self._cum[i - 1]
            along = math.dist((a.x_mm, a.y_mm, a.z_mm), tuple(tcp_mm[:3]))
            done += min(along, seg)
        self.progress = max(self.progress, min(1.0, done / self._total))
        self.line = max(0, self._w[i].line)

    def complete(self) -> None:
        self.progress = 1.0

    @property
    def eta_s(self) -> float:
        return max(0.0, (1.0 - self.progress) * self._duration)
