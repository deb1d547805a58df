"""Recorder benchmark: the highest rate the recorder takes with zero drops, against a raw pyzmq subscriber.

    .venv/bin/python bench/record.py [--duration 2.0] [--quick]

One bus (in this process), one publisher process per phase (raw pyzmq PUB sending valid palpa envelopes at a
paced rate, pre-encoded, seq 1..N), and one subscriber under test for the whole run:

* ``sink``: a raw pyzmq SUB that receives and discards the same stream (counts messages per topic), and
* ``recorder``: ``palpa record`` (the real CLI, its own process) writing MCAP (zstd) to a temporary file.

Three ramps, each run for both contenders in the same run: ~100 B messages one per envelope, the same batched
64 per envelope (what palpa publishers send under load from a callback), and 100 kB messages (MB/s). A phase
passes when every message arrived (drops counted from sequence numbers / counts) AND the subscriber was not
falling behind: the last message was received < 100 ms after it was published (HWM buffers can otherwise hide a
slow subscriber for a short run). The recorder's counts are read from its heartbeat counters and checked
against the file. The last line is one JSON object with every figure; ratios are recorder / sink.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgspec
import zmq

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from palpa.net.address import BusAddress  # noqa: E402
from palpa.net.bus import Bus  # noqa: E402
from palpa.net.wire import HeaderTemplate, decode_header, msgpack_array  # noqa: E402
from palpa.node.node import Node  # noqa: E402
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat  # noqa: E402

MAX_LAG_S = 0.1
SMALL_RATES = [25_000, 50_000, 75_000, 100_000, 125_000, 150_000, 200_000]
BATCH_RATES = [100_000, 200_000, 300_000, 400_000]
LARGE_RATES = [500, 1_000, 2_000, 3_000, 4_000, 6_000]


# ------------------------------------------------------------------------------------------------ children
def role_pub(args: argparse.Namespace) -> None:
    """Warm up on bench/warmup until 'go' on stdin, send N envelopes at the rate, then done markers until EOF."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.PUB)
    sock.sndhwm = 100_000
    sock.connect(args.endpoint)
    node = f"benchpub{os.getpid()}"
    topic = args.topic.encode()
    payload = msgspec.msgpack.encode({"seq": 0, "data": b"x" * args.size})
    warm_t = HeaderTemplate("BenchWarmup", node, False)
    data_t = HeaderTemplate("Bench", node, False)
    done_t = HeaderTemplate("BenchDone", node, False)
    seq = 0
    while not select.select([sys.stdin], [], [], 0.005)[0]:
        seq += 1
        sock.send_multipart([b"bench/warmup", warm_t.pack(seq, time.time_ns()), msgspec.msgpack.encode(os.getpid())])
    sys.stdin.readline()
    n = int(args.rate * args.duration)
    batch = args.batch
    sent = 0
    t0 = time.perf_counter()
    while sent < n:
        due = min(n, int((time.perf_counter() - t0) * args.rate) + 1)
        while sent < due:
            if batch > 1:
                k = min(batch, n - sent)
                stamp = time.time_ns()
                heads = [data_t.pack(sent + i + 1, stamp) for i in range(k)]
                sock.send_multipart([topic, msgpack_array(heads), msgpack_array([payload] * k)])
                sent += k
            else:
                sent += 1
                sock.send_multipart([topic, data_t.pack(sent, time.time_ns()), payload], copy=False)
    elapsed = time.perf_counter() - t0
    seq = 0
    while not select.select([sys.stdin], [], [], 0.01)[0]:
        seq += 1
        sock.send_multipart([topic + b"/done", done_t.pack(seq, time.time_ns()), b"\x80"])
    print(json.dumps({"sent": n, "elapsed_s": elapsed}), flush=True)
    sock.close(1000)
    ctx.term()


def role_sink(args: argparse.Namespace) -> None:
    """Receive and discard; per data topic report the count and how late the last message was."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.SUB)
    sock.connect(args.endpoint)
    sock.setsockopt(zmq.SUBSCRIBE, b"bench")
    counts: dict[bytes, int] = {}
    nbytes: dict[bytes, int] = {}
    last: dict[bytes, tuple[bytes, int]] = {}
    reported: set[bytes] = set()
    warm: set[bytes] = set()
    recv = sock.recv_multipart
    while True:
        frames = recv()
        topic = frames[0]
        if topic.endswith(b"/done"):
            data = topic[:-5]
            if data not in reported:
                reported.add(data)
                head, t_recv = last.get(data, (b"", 0))
                lag = 0.0
                if head:
                    h = decode_header(head) if head[0] & 0xF0 == 0x80 else None
                    stamp = h.stamp if h else msgspec.msgpack.decode(head)[-1]["stamp"]
                    lag = (t_recv - stamp) / 1e9
                print(json.dumps({"topic": data.decode(), "received": counts.get(data, 0),
                                  "bytes": nbytes.get(data, 0), "lag_s": lag}), flush=True)
        elif topic == b"bench/warmup":
            if frames[2] not in warm:  # a new publisher's stream reaches us: its route is up
                warm.add(frames[2])
                print(f"ready {msgspec.msgpack.decode(frames[2])}", flush=True)
        else:
            head = frames[1]
            n = 1 if head[0] & 0xF0 == 0x80 else len(msgspec.msgpack.decode(head))  # a map, or a batch's array
            counts[topic] = counts.get(topic, 0) + n
            nbytes[topic] = nbytes.get(topic, 0) + len(frames[2])
            last[topic] = (frames[1], time.time_ns())


# ------------------------------------------------------------------------------------------------ driver
class Contender:
    """A subscriber under test; ``result(topic)`` waits for its report on one phase."""

    name = ""

    def wait_ready(self, pid: int, timeout: float) -> None: ...

    def result(self, topic: str, timeout: float) -> dict[str, Any]:
        raise NotImplementedError

    def stop(self) -> dict[str, Any]:
        return {}


class Sink(Contender):
    name = "sink"

    def __init__(self, address: BusAddress) -> None:
        self.proc = subprocess.Popen([sys.executable, __file__, "--role", "sink", "--endpoint", address.sub],
                                     stdout=subprocess.PIPE, text=True)
        self.lines: list[str] = []

    def _line(self, timeout: float) -> str | None:
        assert self.proc.stdout is not None
        if select.select([self.proc.stdout], [], [], timeout)[0]:
            return self.proc.stdout.readline().strip()
        return None

    def wait_ready(self, pid: int, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self._line(0.1) == f"ready {pid}":
                return
        raise RuntimeError("sink never saw the warmup stream")

    def result(self, topic: str, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            line = self._line(0.1)
            if line and line.startswith("{"):
                r: dict[str, Any] = json.loads(line)
                if r["topic"] == topic:
                    return r
        return {"topic": topic, "received": 0, "bytes": 0, "lag_s": float("inf"), "timeout": True}

    def stop(self) -> dict[str, Any]:
        self.proc.kill()
        self.proc.wait(5)
        return {}


class RecorderProc(Contender):
    name = "recorder"

    def __init__(self, address: BusAddress, watch: Node, out: Path) -> None:
        self.out = out
        env = dict(os.environ, PALPA_BUS=str(address), PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen([sys.executable, "-m", "palpa.cli.main", "record", "-o", str(out),
                                      "bench/.*", "--force"], env=env, stderr=subprocess.PIPE, text=True)
        self.watch = watch
        self.sub = watch.subscribe(HEARTBEAT_TOPIC, Heartbeat)
        self.beat: Heartbeat | None = None

    def _counters(self, timeout: float) -> Heartbeat | None:
        hb = self.sub.next(timeout)
        while hb is not None and hb.node != "recorder":
            hb = self.sub.next(timeout)
        if hb is not None:
            self.beat = hb
        return hb

    def wait_ready(self, pid: int, timeout: float) -> None:
        """The new publisher's warmup traffic shows up in the recorder's heartbeat counters."""
        base_hb = self.beat.counters.get("bench/warmup") if self.beat else None
        base = base_hb.received if base_hb else 0
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hb = self._counters(0.5)
            warm = hb.counters.get("bench/warmup") if hb else None
            if warm is not None and warm.received > base:
                return
        raise RuntimeError("recorder never received the warmup stream")

    def result(self, topic: str, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hb = self._counters(0.5)
            if hb is not None and topic + "/done" in hb.counters:
                c = hb.counters.get(topic)
                return {"topic": topic, "received": c.received if c else 0, "gaps": c.gaps if c else 0}
        return {"topic": topic, "received": 0, "lag_s": float("inf"), "timeout": True}

    def stop(self) -> dict[str, Any]:
        self.proc.send_signal(2)
        try:
            _, err = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return {"exit": self.proc.returncode, "log": err.strip().splitlines()[-1:] if err else []}


def file_facts(path: Path) -> dict[str, dict[str, Any]]:
    """Per data topic: message count and the lag of its last message (log time - publish time) in the file."""
    from palpa.record.reader import iter_file

    facts: dict[str, dict[str, Any]] = {}
    for m in iter_file(path):
        if m.topic.startswith("bench/") and not m.topic.endswith(("/done", "warmup")):
            f = facts.setdefault(m.topic, {"count": 0, "lag_s": 0.0})
            f["count"] += 1
            f["lag_s"] = (m.log_time - m.publish_time) / 1e9
    return facts


def run_ramp(label: str, rates: list[int], size: int, batch: int, duration: float, contender: Contender,
             address: BusAddress) -> list[dict[str, Any]]:
    phases = []
    for rate in rates:
        topic = f"bench/{label}_{contender.name}_{rate}"
        pub = subprocess.Popen([sys.executable, __file__, "--role", "pub", "--endpoint", address.pub,
                                "--topic", topic, "--rate", str(rate), "--duration", str(duration),
                                "--size", str(size), "--batch", str(batch)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert pub.stdin is not None and pub.stdout is not None
        try:
            contender.wait_ready(pub.pid, 10.0)
            pub.stdin.write("go\n")
            pub.stdin.flush()
            r = contender.result(topic, duration + 30.0)
            pub.stdin.write("stop\n")
            pub.stdin.flush()
            sent = json.loads(pub.stdout.readline())
        finally:
            pub.kill()
            pub.wait(5)
        n = sent["sent"]
        phase = {"rate": rate, "sent": n, "achieved_rate": n / sent["elapsed_s"], **r}
        phase["drops"] = n - r["received"]
        phases.append(phase)
        if "lag_s" in phase:  # the recorder's lag comes from its file, at the end
            _show(label, contender.name, phase)
    return phases


def _passed(p: dict[str, Any]) -> bool:
    return bool(p["drops"] == 0 and p.get("lag_s", 0.0) < MAX_LAG_S)


def _show(label: str, who: str, p: dict[str, Any]) -> None:
    print(f"  {label:6s} {who:8s} {p['rate']:>8d}/s (sent at {p['achieved_rate']:>9.0f}/s): "
          f"received {p['sent'] - p['drops']:>8d}/{p['sent']}  last message {p['lag_s'] * 1e3:8.1f} ms late  "
          f"{'ok' if _passed(p) else 'FAIL'}", file=sys.stderr, flush=True)


def best(phases: list[dict[str, Any]]) -> float:
    """The highest rate that passed (at the rate the publisher actually achieved, if lower)."""
    return max((min(p["rate"], p["achieved_rate"]) for p in phases if _passed(p)), default=0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--role", choices=("pub", "sink"))
    ap.add_argument("--endpoint")
    ap.add_argument("--topic", default="bench/x")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--size", type=int, default=80)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--duration", type=float, default=2.0, help="seconds per phase")
    ap.add_argument("--quick", action="store_true", help="fewer rates (a smoke run)")
    args = ap.parse_args()
    if args.role == "pub":
        role_pub(args)
        return
    if args.role == "sink":
        role_sink(args)
        return

    small, batched, large = SMALL_RATES, BATCH_RATES, LARGE_RATES
    if args.quick:
        small, batched, large = [50_000, 100_000], [200_000], [1_000, 2_000]
    tmp = Path(tempfile.mkdtemp(prefix="palpa-bench-record-"))
    bus = Bus(BusAddress.parse(f"ipc:///tmp/pbr-{os.getpid()}-{secrets.token_hex(2)}"))
    address = bus.start()
    watch = Node(name="bench_watch", bus=address, heartbeat_s=0)
    results: dict[str, Any] = {}
    try:
        sink = Sink(address)
        try:
            results["sink"] = {
                "small": run_ramp("small", small, 80, 1, args.duration, sink, address),
                "batch": run_ramp("batch", batched, 80, 64, args.duration, sink, address),
                "large": run_ramp("large", large, 100_000, 1, args.duration, sink, address),
            }
        finally:
            sink.stop()
        out = tmp / "bench.mcap"
        rec = RecorderProc(address, watch, out)
        try:
            results["recorder"] = {
                "small": run_ramp("small", small, 80, 1, args.duration, rec, address),
                "batch": run_ramp("batch", batched, 80, 64, args.duration, rec, address),
                "large": run_ramp("large", large, 100_000, 1, args.duration, rec, address),
            }
        finally:
            results["recorder_exit"] = rec.stop()
        facts = file_facts(out)
        results["file_bytes"] = out.stat().st_size
        for ramp in results["recorder"].values():
            for p in ramp:  # the file is the truth: counts must match the counters, lag comes from log times
                f = facts.get(p["topic"], {"count": 0, "lag_s": float("inf")})
                p["file_count"] = f["count"]
                p["lag_s"] = f["lag_s"]
                p["drops"] = p["sent"] - f["count"]
        for label, ramp in results["recorder"].items():
            for p in ramp:
                _show(label, "recorder", p)
    finally:
        watch.close(0)
        bus.stop()
        for leftover in tmp.iterdir():
            leftover.unlink()
        tmp.rmdir()

    msg_bytes = len(msgspec.msgpack.encode({"seq": 0, "data": b"x" * 80}))
    summary = {
        "bench": "record",
        "small_msg_bytes": msg_bytes,
        "sink_small_msg_s": best(results["sink"]["small"]),
        "recorder_small_msg_s": best(results["recorder"]["small"]),
        "sink_batch64_msg_s": best(results["sink"]["batch"]),
        "recorder_batch64_msg_s": best(results["recorder"]["batch"]),
        "sink_100kB_MB_s": best(results["sink"]["large"]) * 0.1,
        "recorder_100kB_MB_s": best(results["recorder"]["large"]) * 0.1,
        "target_small_msg_s": 100_000,
        "max_lag_s": MAX_LAG_S,
        "phase_s": args.duration,
    }
    for k in ("small_msg_s", "batch64_msg_s", "100kB_MB_s"):
        base = summary[f"sink_{k}"]
        summary[f"ratio_{k}"] = round(summary[f"recorder_{k}"] / base, 3) if base else None
    summary["meets_target"] = summary["recorder_small_msg_s"] >= summary["target_small_msg_s"]
    summary["recorder_exit"] = results["recorder_exit"].get("exit")
    print(json.dumps({"phases": results}, default=str), file=sys.stderr)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
