"""Service round trip: a blocking ``Client.call`` to a server in another process, over an ipc bus.

    .venv/bin/python bench/service.py [--n 3000] [--rounds 3] [--busy-poll-us 0]

Round trip = request (client -> proxy -> server) + handler + reply (server -> proxy -> client), four ZeroMQ hops
and two Python dispatches each way. Beside it, for scale: the same request/reply as two plain topics (the server
node echoes a message back; what a service adds on top of the bus is the difference) and the in-process
round trip on the in-memory bus (palpa.testing: no sockets, the Python cost of a call alone). Each contender
runs ``--rounds`` times in turns; each round's first 10 % is warm-up. The last line is one JSON object with every
figure (µs) and the ratios to the in-process call.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import palpa  # noqa: E402
from palpa.net.address import BusAddress  # noqa: E402
from palpa.net.bus import Bus  # noqa: E402
from palpa.net.transport import TransportOptions  # noqa: E402
from palpa.testing import GraphHarness  # noqa: E402


class Ping(palpa.Message, frozen=True, kw_only=True):
    """The benchmark request and topic message (~40 bytes of msgpack)."""

    seq: int
    data: bytes = b"x" * 24


class Pong(palpa.Message, frozen=True, kw_only=True):
    seq: int


class Server(palpa.Node):
    """Serves bench/ping and echoes bench/out onto bench/back."""

    def setup(self) -> None:
        self.service("bench/ping", Ping, Pong, lambda r: Pong(seq=r.seq))
        self.back = self.publisher("bench/back", Pong)
        self.subscribe("bench/out", Ping, lambda m: self.back.publish(Pong(seq=m.seq)))


def serve(bus: str, busy_poll_us: int) -> None:
    with Server(name="bench_server", bus=bus, heartbeat_s=0,
                transport_options=TransportOptions(busy_poll_us=busy_poll_us)) as node:
        print("ready", flush=True)
        node.spin()


def percentiles(xs: list[float]) -> dict[str, float]:
    xs = sorted(xs)
    return {"p50": xs[len(xs) // 2], "p90": xs[int(len(xs) * 0.9)], "p99": xs[int(len(xs) * 0.99)],
            "mean": statistics.fmean(xs)}


def run_service(node: palpa.Node, n: int) -> list[float]:
    client = node.client("bench/ping", Ping, Pong)
    if not client.wait_for_service(10):
        raise SystemExit("bench/ping: no server")
    out = []
    for i in range(n):
        t0 = time.perf_counter_ns()
        client.call(Ping(seq=i), timeout_s=5.0)
        out.append((time.perf_counter_ns() - t0) / 1e3)
    return out[n // 10:]


def run_topics(node: palpa.Node, pub: palpa.Publisher[Ping], sub: palpa.Subscription[Pong], n: int) -> list[float]:
    out = []
    for i in range(n):
        t0 = time.perf_counter_ns()
        pub.publish(Ping(seq=i))
        while True:
            got = sub.next(5.0)
            if got is None:
                raise SystemExit("bench/back: no echo")
            if got.seq == i:
                break
        out.append((time.perf_counter_ns() - t0) / 1e3)
    return out[n // 10:]


def run_memory(n: int) -> list[float]:
    with GraphHarness([(Server, None)]) as g:
        client = g.add(palpa.Node, name="caller").client("bench/ping", Ping, Pong)
        assert client.wait_for_service(1)
        out = []
        for i in range(n):
            t0 = time.perf_counter_ns()
            client.call(Ping(seq=i))
            out.append((time.perf_counter_ns() - t0) / 1e3)
    return out[n // 10:]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3000, help="calls per round and contender")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy-poll-us", type=int, default=0, help="both nodes spin this long before blocking")
    ap.add_argument("--serve", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(args.serve, args.busy_poll_us)
        return
    base = f"/tmp/pb-{os.getpid()}"
    with Bus(BusAddress.parse(f"ipc://{base}")) as bus:
        address = str(bus.address)
        server = subprocess.Popen([sys.executable, __file__, "--serve", address, "--busy-poll-us",
                                   str(args.busy_poll_us)], stdout=subprocess.PIPE, text=True)
        try:
            assert server.stdout is not None and server.stdout.readline().strip() == "ready"
            results: dict[str, list[float]] = {"service_ipc": [], "topics_ipc": [], "service_memory": []}
            with palpa.Node(name="bench_client", bus=address, heartbeat_s=0,
                            transport_options=TransportOptions(busy_poll_us=args.busy_poll_us)) as node:
                pub = node.publisher("bench/out", Ping, batch=1)
                sub = node.subscribe("bench/back", Pong)
                pub.wait_for_subscribers(10)
                for _ in range(args.rounds):
                    results["service_ipc"] += run_service(node, args.n)
                    results["topics_ipc"] += run_topics(node, pub, sub, args.n)
                    results["service_memory"] += run_memory(args.n)
        finally:
            server.terminate()
            server.wait(10)
    figures: dict[str, Any] = {k: percentiles(v) for k, v in results.items()}
    base_p50 = figures["service_memory"]["p50"]
    for name, f in figures.items():
        print(f"{name:15s} p50 {f['p50']:8.1f} us  p90 {f['p90']:8.1f} us  p99 {f['p99']:8.1f} us  "
              f"x{f['p50'] / base_p50:5.1f} the in-process call")
    figures["ratio_service_vs_topics_p50"] = figures["service_ipc"]["p50"] / figures["topics_ipc"]["p50"]
    figures["ratio_service_ipc_vs_memory_p50"] = figures["service_ipc"]["p50"] / base_p50
    figures["n"], figures["rounds"], figures["busy_poll_us"] = args.n, args.rounds, args.busy_poll_us
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
