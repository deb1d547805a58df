"""Plugging a node into the shipped scan: ``HardSpots`` watches ``stiffness/sample`` and reports each valid
sample stiffer than ``threshold`` times the median of the last ``window`` samples as a ``HardSpot`` (a message
type of its own) on ``hard_spots``.

``scan_with_hard_spots.yaml`` includes ``launch/scan_sim.yaml`` and adds this node; the scan's recording keeps
the new topic, schema included, with no setting (docs/custom-node.md, "Plug a node into the scan")::

    palpa launch examples/custom_node/scan_with_hard_spots.yaml
"""

from __future__ import annotations

import statistics
from collections import deque

import palpa
from messages import StiffnessSample


class HardSpot(palpa.Message, frozen=True, kw_only=True):
    """A sample much stiffer than those just before it (topic ``hard_spots``)."""

    stamp_ns: int
    x_mm: float
    y_mm: float
    value: float
    """The sample's stiffness, in ``unit``."""
    unit: str
    ratio: float
    """``value`` over the median of the window before it."""


class HardSpots(palpa.Node):
    """``stiffness/sample`` -> ``hard_spots`` (HardSpot) for samples above ``threshold`` x the recent median."""

    class Params(palpa.Params):
        threshold: float = 1.5
        """Report a sample this many times stiffer than the recent median."""
        window: int = 200
        """Samples in the running median (the recent ones, not the whole scan)."""

    params: Params  # typed: mypy checks every self.params.<name>

    def setup(self) -> None:
        if self.params.threshold <= 1 or self.params.window < 3:
            raise palpa.ParamError(f"node {self.name!r}: threshold must be > 1 and window >= 3")
        self.recent: deque[float] = deque(maxlen=self.params.window)
        self.out = self.publisher("hard_spots", HardSpot)
        self.subscribe("stiffness/sample", self.on_sample)

    def on_sample(self, s: StiffnessSample) -> None:
        if not s.valid:
            return
        if len(self.recent) >= 3:
            median = statistics.median(self.recent)
            if median > 0 and s.value > self.params.threshold * median:
                self.out.publish(HardSpot(stamp_ns=s.stamp_ns, x_mm=s.x_mm, y_mm=s.y_mm, value=s.value,
                                          unit=s.unit, ratio=s.value / median))
        self.recent.append(s.value)


if __name__ == "__main__":
    palpa.run_node(HardSpots)
