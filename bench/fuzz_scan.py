"""Hostile fuzz of a running scan (issue 22's acceptance): the air-float sweep of launch/scan_sim.yaml, in-process
(palpa.testing.GraphHarness, mock clock), run twice with the same seeds: once clean, once with N hostile frames
sent on the scan's own topics while it runs (malformed envelopes, empty and oversized batches, sequence numbers
at 0 and 2^64-1, NaN/inf set-points and poses, wrong types, garbage payloads, topics with control characters).

Checks, and prints as one JSON line: every node alive (the scanner ends by itself with exit code 0), no receive
path error, every counter <= 2^63-1, and the fuzzed map equal to the clean one (same inclusions to 0.01 mm).

    .venv/bin/python bench/fuzz_scan.py [--frames 10000] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import tempfile
import time
from pathlib import Path

import msgpack

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nodes.mapping.map_aggregator import MapAggregator  # noqa: E402
from nodes.probe.fibre_reader import FibreReader  # noqa: E402  (after the sys.path line)
from nodes.probe.pressure_controller import PressureController  # noqa: E402
from nodes.probe.stiffness_estimator import AirfloatStiffnessEstimator  # noqa: E402
from nodes.scanner.robot_scanner import RobotScanner  # noqa: E402
from palpa.net.wire import COUNTER_MAX, msgpack_array  # noqa: E402
from palpa.testing import GraphHarness  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PHANTOM = str(REPO / "phantoms" / "airfloat_tumours.yaml")
TOPICS = [b"probe/heights", b"pressure/state", b"pressure/command", b"robot/pose", b"robot/plan",
          b"robot/scan_status", b"stiffness/sample", b"robot/estop_", b"_palpa/clock", b"evil\x1b[2J"]
TYPES = ["ProbeHeights", "PressureState", "PressureCommand", "RobotPose", "ScanPlan", "ScanStatus",
         "StiffnessSample", "Text", "Nope"]
U64 = 2**64 - 1


def hostile(rng: random.Random) -> list[bytes]:
    """One hostile ZeroMQ message (never a valid message of a real type: forging valid data is what CURVE is
    for, not what a receive path can tell)."""
    topic = rng.choice(TOPICS)
    seq = rng.choice([0, 1, 2, U64, U64 - 1, rng.randrange(U64)])
    head = {"type": rng.choice(TYPES), "seq": seq, "stamp": rng.choice([0, U64, -1]), "node": rng.choice(
        ["estimator", "fibre", "pressure", "scanner", "evil"])}
    nan = rng.choice([math.nan, math.inf, -math.inf])
    kind = rng.randrange(9)
    if kind == 0:
        return [topic, b"\x90", b"\x90"]  # the empty batch
    if kind == 1:
        return [topic, bytes(rng.getrandbits(8) for _ in range(rng.randrange(40)))]
    if kind == 2:
        return [topic, *(bytes(rng.getrandbits(8) for _ in range(rng.randrange(30))) for _ in range(3))]
    if kind == 3:  # non-finite numbers where they make no sense
        return [b"pressure/command", msgpack.packb({**head, "type": "PressureCommand"}),
                msgpack.packb({"mode": "ramp", "setpoint_kpa": nan, "rate_kpa_s": nan})]
    if kind == 4:
        return [b"robot/pose", msgpack.packb({**head, "type": "RobotPose"}),
                msgpack.packb({"stamp_ns": 1, "x_mm": nan, "y_mm": 1.0, "z_mm": 1.0})]
    if kind == 5:  # a right header, a payload of the wrong shape
        return [topic, msgpack.packb(head), msgpack.packb(rng.choice([[1, 2], {"x": "y"}, "text", None]))]
    if kind == 6:  # a batch whose arrays disagree, or of a wrong type
        n = rng.randrange(1, 5)
        return [topic, msgpack_array([msgpack.packb({**head, "seq": (seq + i) % U64}) for i in range(n)]),
                msgpack_array([msgpack.packb({"k": i}) for i in range(rng.randrange(6))])]
    if kind == 7:  # a stiffness sample with a NaN position and a string value
        return [b"stiffness/sample", msgpack.packb({**head, "type": "StiffnessSample"}),
                msgpack.packb({"stamp_ns": 1, "model": "airfloat", "x_mm": nan, "y_mm": 1, "z_mm": 1,
                               "value": "stiff", "unit": "kPa", "valid": True})]
    return [topic, msgpack.packb({**head, "seq": -5}), msgpack.packb({})]  # an invalid header


def scan(out: Path, frames: int, seed: int) -> dict[str, object]:
    rng = random.Random(seed)
    g = GraphHarness()
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 36.0}, heartbeat_s=1.0)
    g.add(FibreReader, {"phantom": PHANTOM, "seed": 3}, heartbeat_s=1.0)
    g.add(AirfloatStiffnessEstimator, {"geometry": PHANTOM.replace("/phantoms/", "/phantoms/measured/")}, heartbeat_s=1.0)
    mapper = g.add(MapAggregator, {"output_dir": str(out)}, heartbeat_s=1.0)
    scanner = g.add(RobotScanner, {"region_mm": [2, 2, 58, 58], "spacing_mm": 4.0, "speed_mm_s": 40.0,
                                   "contact_z_mm": 5.0, "home_mm": [2, 2, 20], "watchdog_s": 0.5},
                    heartbeat_s=1.0)
    sent = steps = 0
    per_step = max(1, frames // 60)
    while not scanner.is_shutdown:
        g.advance(0.5)
        steps += 1
        for _ in range(min(per_step, frames - sent)):
            g.publish_raw(hostile(rng))
            sent += 1
        g.clear()
    while sent < frames:  # the scan ended early: the rest against the idle graph
        g.publish_raw(hostile(rng))
        sent += 1
    g.advance(1.0)
    counters = [c for n in g.nodes for s in n.counters().values()
                for c in (s.received, s.gaps, s.duplicates, s.restarts, s.decode_errors)]
    result = {
        "frames": sent,
        "nodes_alive": sum(not n.is_shutdown for n in g.nodes if n is not scanner) + (scanner.exit_code == 0),
        "nodes": len(g.nodes),
        "scanner_exit": scanner.exit_code,
        "map_incomplete": mapper.incomplete,
        "internal_errors": sum(n._rx.internal_errors for n in g.nodes),
        "handler_errors": sum(n.handler_errors for n in g.nodes),
        "decode_errors": sum(s.decode_errors for n in g.nodes for s in n.counters().values()),
        "max_counter": max(counters),
        "counters_sane": max(counters) <= COUNTER_MAX,
        "inclusions": json.loads((out / "inclusions.json").read_text()),
    }
    g.close()
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        clean = scan(Path(tmp) / "clean", 0, args.seed)
        t1 = time.perf_counter()
        fuzzed = scan(Path(tmp) / "fuzzed", args.frames, args.seed)
        t2 = time.perf_counter()
    same = len(clean["inclusions"]) == len(fuzzed["inclusions"]) and all(  # type: ignore[arg-type]
        math.dist((a["x_mm"], a["y_mm"]), (b["x_mm"], b["y_mm"])) < 0.01
        for a, b in zip(clean["inclusions"], fuzzed["inclusions"], strict=True))  # type: ignore[call-overload]
    ok = bool(same and fuzzed["nodes_alive"] == fuzzed["nodes"] and fuzzed["internal_errors"] == 0
              and fuzzed["counters_sane"] and not fuzzed["map_incomplete"])
    print(f"clean scan {t1 - t0:.1f} s, fuzzed scan {t2 - t1:.1f} s (ratio {(t2 - t1) / (t1 - t0):.2f})")
    print(json.dumps({"ok": ok, "map_equal": same, "clean_inclusions": len(clean["inclusions"]),  # type: ignore[arg-type]
                      **{k: v for k, v in fuzzed.items() if k != "inclusions"}}))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
