"""The emulated controller's time: :class:`ControllerClock` runs its 2 ms cycles as far as a given clock says.

The server (server.py) runs it on the monotonic clock, as a controller runs in wall time; an in-process test runs it
on its harness's clock (``ControllerClock(controller, g.clock.now_ns)``), so that the emulated arm and the graph
driving it share one simulated time and a starved test process cannot let the arm run on ahead (what the
``--clock-file`` regime of tests/followed_clock.py approximates across processes).
"""

from __future__ import annotations

from collections.abc import Callable

from emulators.ur.controller import UrController
from models.arm import TICK_S

__all__ = ["TICK_NS", "ControllerClock"]

TICK_NS = round(TICK_S * 1e9)


class ControllerClock:
    """Steps ``controller`` one cycle per :data:`TICK_NS` of ``clock`` (ns) since the first reading.

    ``max_catchup`` bounds the cycles one :meth:`step` runs: further ones are skipped, and logged, as a controller
    that could not keep up (the arm then lags its clock rather than jumping).
    """

    def __init__(self, controller: UrController, clock: Callable[[], int], *, max_catchup: int = 50) -> None:
        self.controller = controller
        self._clock = clock
        self._t0 = clock()
        self._done = 0
        self._max_catchup = max_catchup

    def next_due_ns(self) -> int:
        """When (on the clock) the next cycle falls due."""
        return self._t0 + (self._done + 1) * TICK_NS

    def run_ahead(self, done: Callable[[], bool], max_ticks: int) -> int | None:
        """Run cycles beyond the clock's now until ``done()`` holds, at most ``max_ticks``: a blocking client call
        that waits on the controller while its caller's clock cannot move (emulators.ur.local). They count as the
        clock's next cycles: :meth:`step` runs none until the clock has passed them. How many ran, or None if
        ``done()`` never held."""
        ctl = self.controller
        for n in range(max_ticks + 1):
            if done():
                return n
            if n < max_ticks:
                with ctl.lock:
                    ctl.tick()
                self._done += 1
        return None

    def step(self, hold_at: int | None = None, *, batch: int = 5,
             between: Callable[[], object] | None = None) -> int:
        """Run the cycles due by the clock's now; returns how many ran. The arm is held once it has moved
        ``hold_at`` cycles (None: never held; the server's ``--clock-file`` lead). The controller's lock is taken
        per ``batch`` of cycles and ``between()`` called after each, so that client input (commands, watchdog kicks)
        is applied while a late controller catches up."""
        ctl = self.controller
        target = (self._clock() - self._t0) // TICK_NS
        n = target - self._done
        if n > self._max_catchup:
            ctl.log(f"controller lagging: skipping {n - self._max_catchup} ticks")
            n = self._max_catchup
        self._done = max(self._done, target)
        for start in range(0, max(0, n), batch):
            with ctl.lock:
                for _ in range(min(batch, n - start)):
                    ctl.tick(hold=hold_at is not None and ctl.arm_steps >= hold_at)
            if between is not None:
                between()
        return max(0, n)
