"""What the machine itself costs a benchmark: CPU time the hypervisor took, and how late a sleeping thread wakes.

Shared by bench/bus.py and bench/replay.py (they run as scripts, so this directory is on their import path).
"""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["sleep_loop_lateness_ns", "steal_ticks"]


def steal_ticks() -> int:
    """CPU time the hypervisor took from this VM so far (USER_HZ ticks, all CPUs); 0 where unknown."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(fields[8]) if fields[0] == "cpu" and len(fields) > 8 else 0


def sleep_loop_lateness_ns(n: int, period_ns: int = 1_000_000) -> list[int]:
    """How late (ns) a thread that sleeps until each of ``n`` ticks wakes, with no messaging: the floor under
    anything that waits in the kernel. It sleeps to 0.1 ms before each tick, then spins, like a careful player."""
    start = time.perf_counter_ns()
    late = []
    for i in range(n):
        due = start + i * period_ns
        while (left := due - time.perf_counter_ns()) > 0:
            if left > 200_000:
                time.sleep((left - 100_000) / 1e9)
        late.append(time.perf_counter_ns() - due)
    return late
