"""A simulated graph whose time stands still (issue 39: one forged tick froze a scan for 7 minutes, and Ctrl-C then
ended it with exit 0): the launcher watches the clock from outside, warns, ends it non-zero, and a Ctrl-C on it ends
non-zero too (palpa.launch.clockwatch)."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from palpa.launch.clockwatch import ClockWatch
from palpa.runtime_msgs import ClockTick
from tests.procs import ProcessGroup, wait_until
from tests.test_launch_supervisor import TESTS, launch, write


def test_the_watch_counts_wall_time_from_the_last_move_of_simulated_time() -> None:
    wall = [100.0]
    watch = ClockWatch(8.0, wall=lambda: wall[0])
    watch.on_tick(ClockTick(sim_ns=5, hold=True))  # a held start is not time standing still
    wall[0] += 30
    assert watch.verdict() == ("", "")
    watch.on_tick(ClockTick(sim_ns=10**9))
    for _ in range(3):  # the clock repeats the same instant every wall second: still standing
        wall[0] += 1.5
        watch.on_tick(ClockTick(sim_ns=10**9))
    verdict, why = watch.verdict()
    assert verdict == "stalled" and "has not moved for 4 s" in why and "stuck at 1.000 s" in why
    assert watch.verdict() == ("", "")  # warned once per stall
    wall[0] += 4.5
    verdict, why = watch.verdict()
    assert verdict == "frozen" and "has not moved for 9 s" in why
    watch.on_tick(ClockTick(sim_ns=2 * 10**9))  # it moves again: a new count
    assert watch.verdict() == ("", "") and watch.still_s() == 0


def _frozen_graph(tmp_path: Path, frozen_after_s: float) -> Path:
    return write(tmp_path, f"""
        python_path: [{json.dumps(str(TESTS))}]
        nodes:
          - name: clock
            node: palpa.timing.simclock:ClockSource
            params: {{time_scale: 1.0, rate_hz: 100.0, frozen_after_s: {frozen_after_s}}}
          - name: freezer
            node: launch_node_classes:Freezer
            env: {{PALPA_SIM_CLOCK: "1"}}
            params: {{after_s: 0.5, hold_s: 120.0}}
    """)


@pytest.mark.system
def test_a_graph_whose_time_stands_still_is_ended_non_zero_with_the_reason(procs: ProcessGroup,
                                                                          tmp_path: Path) -> None:
    proc = launch(procs, _frozen_graph(tmp_path, 3.0), tmp_path / "run")
    assert proc.wait(90) == 1, proc.output()
    out = proc.output()
    assert "freezing for 120 s" in out
    assert "stopping: simulated time has not moved for 3 s (wall clock), stuck at" in out
    assert "exit code 1" in out.splitlines()[-1]


@pytest.mark.system
def test_ctrl_c_on_a_graph_whose_time_stands_still_ends_non_zero(procs: ProcessGroup, tmp_path: Path) -> None:
    proc = launch(procs, _frozen_graph(tmp_path, 12.0), tmp_path / "run")
    wait_until(lambda: "the launch ends with exit code 1 after 12 s, or on Ctrl-C" in proc.output(), 90,
               "the launcher's warning that simulated time stands still")
    proc.popen.send_signal(signal.SIGINT)
    assert proc.wait(60) == 1, proc.output()
    out = proc.output()
    assert "stopping: stopped by SIGINT while simulated time has not moved for" in out
