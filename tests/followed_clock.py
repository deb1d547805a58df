"""The clock a test's loop runs a real-time emulator on (the UR emulator's ``--clock-file``, emulators.clock_file)."""

from __future__ import annotations

import time
from collections.abc import Callable

from emulators.clock_file import ClockWriter


class FollowedClock:
    """Each :meth:`tick` sleeps a little, advances this clock by the pass's wall time, at most ``MAX_STEP_S``, and
    publishes it to the emulator, so that a stall of the test's process (starved by the suite's other workers, or in
    a call holding the GIL: a second and more on a loaded machine) holds the emulated arm, within the emulator's
    0.1 s lead, instead of letting it run on unread. ``advance`` moves the test's own graph by the same step (a
    harness's ``advance``). On the rig a PC that stalls is the RTDE watchdog's business (tests/test_robot_drivers.py).
    """

    MAX_STEP_S = 0.02

    def __init__(self, writer: ClockWriter, advance: Callable[[float], object] | None = None) -> None:
        self.writer, self.advance, self.now_ns, self.last = writer, advance, 1, time.monotonic()
        writer.write(self.now_ns)

    def tick(self, sleep_s: float = 0.005) -> float:
        """One pass: returns the step (s) the clock advanced by."""
        time.sleep(sleep_s)
        now = time.monotonic()
        step = min(now - self.last, self.MAX_STEP_S)
        self.last = now
        self.now_ns += int(step * 1e9)
        if self.advance is not None:
            self.advance(step)
        self.writer.write(self.now_ns)
        return step
