"""Running an adaptive palpation launch on the UR emulator (issue 20), shared by the air-float and camera probes'
tests: the launch in wall-clock time, what every such run must show, and what it recorded."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from emulators.ur.process import UrEmulatorProcess
from messages import RobotPose, StiffnessSample
from palpa.record.reader import iter_bag, resolve_bag_paths
from tests.procs import ProcessGroup, palpa_cmd
from tests.test_launch_smoke import REPO


@dataclass
class AdaptiveRun:
    """What one run left: planner.json, and the recorded poses, stiffness samples and topic names."""

    plan: dict[str, Any]
    poses: list[RobotPose]
    samples: list[StiffnessSample]
    topics: set[str]


def run_adaptive_on_ur_emulator(procs: ProcessGroup, run: Path, launch: str, home_mm: tuple[float, float, float],
                                region: tuple[float, float, float, float], probes: int,
                                args: list[str]) -> AdaptiveRun:
    """Run ``launch`` (a file under launch/) with the ur_rtde driver against a fresh UR emulator homed at
    ``home_mm`` (tool down), the planner in ``region`` with a budget of ``probes`` and ``args``, and check what every
    run must show: a clean exit of both; every probe asked for run, a refusal only because the wall clock of a busy
    machine made the probe's data late (the scanner's watchdog), retried, never given up; every point in the
    region; the map written."""
    x, y, z = home_mm
    emu = UrEmulatorProcess.on_random_loopback(["--home", f"{x},{y},{z},0,{math.pi},0"])
    emu.start()
    try:
        p = procs.start(palpa_cmd(
            "launch", str(REPO / "launch" / launch), "--run-dir", str(run), "--no-progress",
            f"robot_host:={emu.host}", f"region_mm:={list(region)}", f"max_probes:={probes}", *args), cwd=str(REPO))
        code = p.wait(180)
        assert code == 0, p.output()[-6000:]
    finally:
        assert emu.stop() == 0, emu.log()[-3000:]
    plan = json.loads((run / "map" / "planner.json").read_text())
    logs = "\n".join(f"--- {n}\n" + (run / n).read_text()[-3000:] for n in ("planner.log", "scanner.log")
                     if (run / n).exists())
    assert plan["probes"] == probes and not plan["given_up"], f"{plan}\n{logs}"
    planner_log = (run / "planner.log").read_text() if (run / "planner.log").exists() else ""
    refusals = [line for line in planner_log.splitlines() if " refused" in line]
    # late estimates refuse nothing: the scanner's answer waits for the estimator to catch up (nodes/scanner/scan_control.py);
    # a starved camera can drop the frames of a press, so that none of its estimates there is valid: refused too; a
    # starved sensor or pressure controller stops the arm on the probe's path (the scanner's watchdog), and the
    # scanner stays up. Each must be retried and the point then answered
    causes = ("no fresh probe data", "none of its estimates was", "the scanner stopped the arm", "no fresh data to move")
    assert len(refusals) == plan["refused"] and all(
        any(c in r for c in causes) and "retrying" in r for r in refusals), f"{plan}\n{logs}"
    answered = {(round(px, 1), round(py, 1)) for px, py in plan["points"]}
    for r in refusals:
        at = re.search(r"probe at \(([-\d.]+), ([-\d.]+)\) mm refused", r)
        assert at and (round(float(at[1]), 1), round(float(at[2]), 1)) in answered, f"{r}\n{plan}"
    assert all(region[0] <= px <= region[2] and region[1] <= py <= region[3] for px, py in plan["points"])
    assert (run / "map" / "map.npz").exists() and (run / "map" / "inclusions.json").exists()
    out = AdaptiveRun(plan, [], [], set())
    for m in iter_bag(resolve_bag_paths(str(run / "recording.mcap"))):
        out.topics.add(m.topic)
        if m.topic == "robot/pose":
            out.poses.append(msgspec.msgpack.decode(m.payload, type=RobotPose))
        elif m.topic == "stiffness/sample":
            out.samples.append(msgspec.msgpack.decode(m.payload, type=StiffnessSample))
    return out
