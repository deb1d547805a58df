"""The RTDE watchdog as the UR driver (nodes.drivers.robot_urrtde) keeps it: armed on the controller with
``setWatchdog(hz)``, kicked at four times the rate it asks for, and the longest gap between kicks since it was armed,
from which :meth:`RtdeWatchdog.stop_cause` tells whether a program that stopped under the driver was stopped by the
watchdog (this process or the link stalled) or by something else (the pendant, the dashboard, another client).

Kicks are timed on the clock handed in (the node's), which the controller's watchdog follows: the wall for a robot,
the graph's for an emulated controller stepped on it. Split from nodes.drivers.robot_urrtde, which holds the lock
these run under and calls them from its monitor thread and its callers' polls.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["RtdeWatchdog"]

_WATCHDOG_LATENCY_S = 0.05
"""The least slack granted between a kick's sending and its arrival when telling a watchdog stop (stop_cause)."""


class RtdeWatchdog:
    """The watchdog at ``hz`` (None: none is set) on ``clock`` (ns)."""

    def __init__(self, hz: float | None, clock: Callable[[], int]) -> None:
        self.hz = hz
        self._clock = clock
        self.last_kick = 0
        """When (clock ns) the watchdog was last kicked or armed."""
        self.kick_gap = 0
        """The longest time between two watchdog kicks since it was last armed (clock ns)."""

    def arm(self, rc: Any) -> None:
        """Set the watchdog on control interface ``rc`` (a fresh control script needs it again)."""
        if self.hz is not None:
            rc.setWatchdog(self.hz)
            self.last_kick = self._clock()
            self.kick_gap = 0

    def kick(self, rc: Any) -> None:
        """Kick the RTDE watchdog at four times the rate it asks for (a clock that stepped back kicks at once)."""
        if self.hz is None:
            return
        now = self._clock()
        if not 0 <= now - self.last_kick < 0.25e9 / self.hz:
            self.kick_gap = max(self.kick_gap, now - self.last_kick)
            rc.kickWatchdog()
            self.last_kick = now

    def stop_cause(self, now: int | None = None) -> str:
        """Why the program may have stopped: whether this driver let the watchdog starve (its longest gap between
        kicks since the watchdog was armed: a stalled process or link) or kept it fed (the pendant, the dashboard,
        another client)."""
        if self.hz is None:
            return "stopped from the pendant or dashboard; no RTDE watchdog was set"
        # the controller times its watchdog on its own clock, which the clock handed in follows (the wall for a
        # robot): so are the kicks, here and in kick
        now = self._clock() if now is None else now
        gap, allowed = max(self.kick_gap, now - self.last_kick) / 1e9, 1.0 / self.hz
        # the controller times a kick from its arrival, this driver from its sending: a kick that left on time can
        # arrive late over a busy link or to a busy controller, so a gap this near the limit may have starved it
        near = max(_WATCHDOG_LATENCY_S, 0.1 * allowed)
        if gap > allowed - near:
            over = "over" if gap > allowed else f"within {near:.2g} s of"
            return (f"RTDE watchdog: this driver did not kick it for {gap:.2f} s, {over} the {allowed:.2g} s it "
                    "allows: this process stalled (CPU starved, or a blocking call) or the link did")
        return (f"not the RTDE watchdog: this driver kicked it at least every {gap:.2f} s (it allows {allowed:.2g} s); "
                "stopped from the pendant or dashboard, or by another client")
