"""Foxglove bridge acceptance figures during the demo scan (issue 18).

    .venv/bin/python bench/viz.py [--quick] [--no-baseline]

Runs ``palpa launch launch/scan_sim.yaml viz:=true viz_port:=0`` and, beside it:

* a palpa subscriber on the bus (the reference): every ``robot/pose`` stamp the graph published, the scan's
  progress, and the bridge's pid from its heartbeat;
* client A, a Foxglove WebSocket client (tests/foxglove_client.py) subscribed to every channel from the start:
  the share of the reference's ``robot/pose`` messages (from A's first one on) that A received;
* client B, joining when the scan is 40 % done: seconds from opening the connection until it holds
  ``map/stiffness`` and ``robot/plan`` (and the views ``viz/map``, ``viz/plan``); then B drops its TCP connection
  without a close handshake, and the scan must still end normally;
* the bridge's CPU time (utime + stime from /proc) over its wall time: the share of one core it used.

Then the same scan without the bridge (unless --no-baseline): the map and the inclusions must be the same
(the simulated sensors are noisy, so "the same" is within the run-to-run spread: --spread measures it with a
second scan without the bridge). The last line is one
JSON object with every figure; the machine's load average is in it (this machine is shared).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from foxglove_client import FoxgloveClient  # noqa: E402

import messages  # noqa: E402, F401
from messages import RobotPose, ScanStatus  # noqa: E402
from palpa.node.node import Node  # noqa: E402
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat  # noqa: E402

QUICK = ["spacing_mm:=6.0", "region_mm:=[2.0, 2.0, 38.0, 38.0]"]
TICK = os.sysconf("SC_CLK_TCK")


def wait_file(path: Path, proc: subprocess.Popen[bytes], timeout: float) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and path.read_text().strip():
            return path.read_text().strip()
        if proc.poll() is not None:
            raise SystemExit(f"launch exited {proc.returncode} before {path.name} appeared")
        time.sleep(0.05)
    raise SystemExit(f"no {path} after {timeout} s")


def cpu_s(pid: int) -> float | None:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def launch(run_dir: Path, args: list[str]) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "palpa.cli.main", "launch", str(REPO / "launch/scan_sim.yaml"), "--run-dir",
           str(run_dir), "--no-progress", *args]
    log = open(run_dir.parent / f"{run_dir.name}.out", "wb")  # noqa: SIM115 (lives as long as the child)
    return subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def with_viz(run_dir: Path, args: list[str], timeout: float) -> dict[str, Any]:
    proc = launch(run_dir, ["viz:=true", "viz_port:=0", *args])
    bus = wait_file(run_dir / "bus.address", proc, 60)
    url = wait_file(run_dir / "viz.address", proc, 60)
    poses: list[int] = []
    progress = [0.0]
    viz_pid: list[int] = []

    ref = Node(name="bench_ref", bus=bus, heartbeat_s=0)
    ref.subscribe("robot/pose", RobotPose, lambda m: poses.append(m.stamp_ns))
    ref.subscribe("robot/scan_status", ScanStatus, lambda s: progress.__setitem__(0, s.progress))
    ref.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda h: viz_pid.append(h.pid) if h.node == "viz" and not viz_pid
                  else None)

    stop = threading.Event()
    a = FoxgloveClient(url).open()

    def pump_a() -> None:
        while not stop.is_set():
            a.subscribe()  # every channel, including ones advertised later
            a.pump(0.2)

    ta = threading.Thread(target=pump_a, daemon=True)
    ta.start()
    join: dict[str, Any] = {}
    cpu_first: tuple[float, float] | None = None
    cpu_last: tuple[float, float] | None = None
    end = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < end:
        ref.spin_once(0.05)
        if viz_pid:
            c = cpu_s(viz_pid[0])
            if c is not None:
                cpu_last = (time.monotonic(), c)
                cpu_first = cpu_first or cpu_last
        if not join and progress[0] >= 0.4:
            join = join_mid_scan(url)
    stop.set()
    ta.join(2)
    a.close()
    code = proc.wait(30) if proc.poll() is None else proc.returncode
    ref.close()
    got = {m.data["stamp_ns"] for m in a.of("robot/pose")}
    first = min(got) if got else 0
    expected = [s for s in poses if s >= first]
    received = sum(1 for s in expected if s in got)
    cpu = None
    if cpu_first and cpu_last and cpu_last[0] > cpu_first[0]:
        cpu = (cpu_last[1] - cpu_first[1]) / (cpu_last[0] - cpu_first[0])
    stats = a.of("_palpa/viz/stats")
    last = stats[-1].data if stats else {}
    dropped = {t: v["dropped"] for t, v in last.get("topics", {}).items() if v["dropped"]}
    return {"exit_code": code, "pose_published": len(expected), "pose_received": received,
            "bridge_dropped": dropped if stats else None, "bridge_sent": sum(
                v["sent"] for v in last.get("topics", {}).values()) if stats else None,
            "pose_share": received / len(expected) if expected else None, "join": join,
            "bridge_cpu_share_of_one_core": cpu, "bridge_cpu_window_s": cpu_last[0] - cpu_first[0] if cpu_first
            and cpu_last else None, "client_a_messages": len(a.messages)}


def join_mid_scan(url: str) -> dict[str, Any]:
    """Client B: connect, subscribe to what is advertised, time until it holds the latched map and plan."""
    t0 = time.monotonic()
    b = FoxgloveClient(url).open()
    want = ("map/stiffness", "robot/plan", "viz/map", "viz/plan")
    have: dict[str, float] = {}
    deadline = t0 + 10
    while len(have) < len(want) and time.monotonic() < deadline:
        b.subscribe()
        b.pump(0.01)
        for t in want:
            if t not in have and b.of(t):
                have[t] = b.of(t)[0].at - t0
    b.close_abruptly()
    out: dict[str, Any] = {f"{t}_s": have.get(t) for t in want}
    out["map_and_plan_s"] = max(have.get("map/stiffness", math.inf), have.get("robot/plan", math.inf))
    return out


def compare(a: Path, b: Path) -> dict[str, Any]:
    ma, mb = np.load(a / "map" / "map.npz"), np.load(b / "map" / "map.npz")
    sa, sb = ma["stiffness"], mb["stiffness"]
    both = np.isfinite(sa) & np.isfinite(sb)
    rel = np.abs(sa[both] / sb[both] - 1) if both.any() else np.array([np.nan])
    ia = json.loads((a / "map" / "inclusions.json").read_text())
    ib = json.loads((b / "map" / "inclusions.json").read_text())
    dist = [min(math.dist((p["x_mm"], p["y_mm"]), (q["x_mm"], q["y_mm"])) for q in ib) for p in ia] if ib else []
    return {"cells_viz": int(np.isfinite(sa).sum()), "cells_no_viz": int(np.isfinite(sb).sum()),
            "map_median_rel_diff": float(np.median(rel)), "map_max_rel_diff": float(rel.max()),
            "inclusions_viz": len(ia), "inclusions_no_viz": len(ib),
            "inclusion_max_offset_mm": max(dist) if dist else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a smaller raster (6 mm lines over 36 mm)")
    ap.add_argument("--no-baseline", action="store_true", help="skip the scan without the bridge")
    ap.add_argument("--spread", action="store_true",
                    help="also a second scan without the bridge: the run-to-run spread of the noisy simulation")
    ap.add_argument("--timeout", type=float, default=600)
    args = ap.parse_args()
    extra = QUICK if args.quick else []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="palpa-viz-") as tmp:
        t0 = time.monotonic()
        viz = with_viz(Path(tmp) / "viz", extra, args.timeout)
        viz["wall_s"] = time.monotonic() - t0
        print(f"with the bridge: {json.dumps(viz)}", flush=True)
        result: dict[str, Any] = {"scan": "quick" if args.quick else "launch/scan_sim.yaml defaults", "viz": viz}
        if not args.no_baseline:
            proc = launch(Path(tmp) / "base", extra)
            result["baseline_exit_code"] = proc.wait(args.timeout)
            result["unchanged"] = compare(Path(tmp) / "viz", Path(tmp) / "base")
            if args.spread:
                proc = launch(Path(tmp) / "base2", extra)
                result["spread_exit_code"] = proc.wait(args.timeout)
                result["spread_without_bridge"] = compare(Path(tmp) / "base2", Path(tmp) / "base")
    result["loadavg_before"] = load_before
    result["loadavg_after"] = os.getloadavg()
    result["cores"] = os.cpu_count()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
