"""Replay timing benchmark: how close to its schedule `palpa play` sends each message of a 1 kHz recording.

    .venv/bin/python bench/replay.py [--n 3000] [--realtime]

A bag of N messages 1 ms apart is written, a bus runs in this process, `palpa play` (the real CLI, its own
process) replays it, and a watcher node here reads the publish stamp the player puts in each envelope: the error
of a message is its send time against its scheduled time, up to the constant start offset (the median). Also
reports the CPU time the hypervisor took from the VM during the replay (/proc/stat steal), which no process can
avoid. The baseline is a plain Python loop in this process sleeping to the same schedule (the best a Python
player can do on this machine at this moment). The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine import sleep_loop_lateness_ns, steal_ticks  # noqa: E402

from messages import Text  # noqa: E402
from palpa.net.address import BusAddress  # noqa: E402
from palpa.net.bus import Bus  # noqa: E402
from palpa.node.node import Node, RawMessage  # noqa: E402
from palpa.record.testing import Rec, write_bag  # noqa: E402

MS = 1_000_000
T0 = 1_700_000_000_000_000_000


def percentiles(offsets_ns: list[int]) -> dict[str, float]:
    base = statistics.median(offsets_ns)
    errors = sorted(abs(o - base) / MS for o in offsets_ns)
    return {"p50_ms": round(errors[len(errors) // 2], 4), "p99_ms": round(errors[int(0.99 * (len(errors) - 1))], 4),
            "max_ms": round(errors[-1], 4)}


def baseline(n: int) -> dict[str, float]:
    """A sleeping loop on the same schedule: the machine's own timer/wake-up error."""
    return percentiles(sleep_loop_lateness_ns(n, MS))


def replay(n: int, realtime: bool) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        payload = msgspec.msgpack.encode(Text(text="imu sample", stamp_ns=0))
        bag = write_bag(Path(tmp) / "khz.mcap", [Rec("imu", T0 + i * MS, payload, i + 1) for i in range(n)])
        bus = Bus(BusAddress.parse(f"ipc:///tmp/pr-{secrets.token_hex(3)}"))
        address = bus.start()
        watch = Node(name="watch", bus=address, heartbeat_s=0)
        got: list[RawMessage] = []
        watch.subscribe_raw("imu", got.append)
        argv = [sys.executable, "-m", "palpa.cli.main", "play", str(bag), *(["--realtime"] if realtime else [])]
        proc = subprocess.Popen(argv, env={**os.environ, "PALPA_BUS": str(address)},
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 60
            while not got and time.monotonic() < deadline and proc.poll() is None:
                watch.spin_once(0.05)
            steal = steal_ticks()
            while len(got) < n and time.monotonic() < deadline and proc.poll() is None:
                watch.spin_once(0.05)
            watch.spin_once(0.2)  # what the player sent just before it exited
            stolen_ms = (steal_ticks() - steal) * 10
            proc.wait(10)
        finally:
            proc.kill()
            watch.close(0)
            bus.stop()
    offsets = [r.header.stamp - (T0 + (r.header.seq - 1) * MS) for r in got]
    return {"received": len(got), "lost": n - len(got), **percentiles(offsets), "stolen_ms": stolen_ms}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--realtime", action="store_true", help="run the player with --realtime (SCHED_FIFO)")
    args = ap.parse_args()
    results = {"n": args.n, "load": round(os.getloadavg()[0], 2), "sleep_loop": baseline(args.n),
               "palpa_play": replay(args.n, args.realtime)}
    for name in ("sleep_loop", "palpa_play"):
        r = results[name]
        print(f"{name:<12} p50 {r['p50_ms']:.3f} ms  p99 {r['p99_ms']:.3f} ms  max {r['max_ms']:.3f} ms")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
