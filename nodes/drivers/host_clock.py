"""The clock a driver stamps with when its node hands it none: the host's wall clock (the bus's time base).

A node always hands its driver its own clock (``clock=self.clock.now_ns``), so that stamps and the driver's time
limits follow the node's time, simulated or not; this default serves a driver used on its own (a script, a test of
the driver against its device). It lives here, apart, so that no driver reads the wall clock itself
(tests/test_architecture.py)."""

from __future__ import annotations

import time

__all__ = ["host_ns"]


def host_ns() -> int:
    """Now on the host's wall clock, in ns since the Unix epoch."""
    return time.time_ns()
