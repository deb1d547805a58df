"""Across hosts: throughput and p99 latency over a veth link between Linux network namespaces, with and without
CURVE, palpa against raw pyzmq over the same link in the same run (issue 22).

    sudo PYTHONPATH=$PWD .venv/bin/python bench/multihost.py [--n 50000] [--latency-n 3000] [--rounds 3]

Needs root and iproute2 (tests/netns.py makes three namespaces on a bridge: host 1 runs the CURVE bus, host 2 the
publisher, host 3 the subscriber; both are child processes). Each contender sends N ~100-byte typed messages from
host 2 as fast as it can (throughput, losses = N - received), then 1 kHz for the latency run (publish stamp ->
receive; both namespaces share this machine's clock; the first 10 % is warm-up). Contenders take turns for
--rounds rounds; each reports its median throughput and the percentiles of all its latency samples pooled:

* raw pyzmq PUB -> SUB, host 2 -> host 3, in plaintext and with CURVE (the SUB is the CURVE server);
* palpa, a topic published direct (host 2 -> host 3, the publisher's own CURVE socket, palpa.net.direct);
* palpa through the bus (host 2 -> host 1 -> host 3, two crossings of the link, CURVE on both).

palpa has no plaintext contender: its bus refuses to listen beyond loopback without CURVE, and a node publishes
direct beyond loopback only with CURVE. Ratios compare palpa with raw pyzmq with CURVE (the same work on the
wire), and raw CURVE with raw plaintext (what the encryption costs). The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import msgspec
import zmq
import zmq.auth

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]

from bus import HWM, Blob, Counter, make_msg, pace  # noqa: E402

import palpa  # noqa: E402
from palpa.net.transport import TransportOptions  # noqa: E402

PORT = 47000
IDLE_S = 2.0


# ---------------------------------------------------------------- roles (child processes, in a namespace)
def _curve(sock: zmq.Socket[bytes], keys: Path, server: bool) -> None:
    if server:
        sock.curve_publickey, sock.curve_secretkey = zmq.auth.load_certificate(str(keys / "server.key_secret"))
        sock.curve_server = True
    else:
        sock.curve_publickey, sock.curve_secretkey = zmq.auth.load_certificate(str(keys / "node.key_secret"))
        sock.curve_serverkey = zmq.auth.load_certificate(str(keys / "server.key"))[0]


def _raw_socket(args: argparse.Namespace, kind: int, server: bool) -> tuple[zmq.Context[zmq.Socket[bytes]],
                                                                          zmq.Socket[bytes]]:
    """A raw pyzmq socket of its own context with the bench's queues, with CURVE keys for ``zmq-curve``."""
    ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    sock = ctx.socket(kind)
    sock.sndhwm = sock.rcvhwm = HWM
    if args.kind == "zmq-curve":
        _curve(sock, Path(args.keys), server)
    return ctx, sock


def role_sub(args: argparse.Namespace) -> None:
    """Receive until N are in or nothing came for IDLE_S after the first; print the Counter's result as JSON."""
    counter = Counter(args.n)
    deadline = time.monotonic() + 60
    if args.kind.startswith("zmq"):
        _, sub = _raw_socket(args, zmq.SUB, server=True)
        sub.subscribe(b"bench")
        sub.bind(args.endpoint)
        dec = msgspec.msgpack.Decoder(Blob)
        print("ready", flush=True)

        def poll() -> None:
            if sub.poll(50):
                for _ in range(1000):
                    try:
                        frames = sub.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    counter.hit(dec.decode(frames[1]))
    else:
        node = palpa.Node(name="bench_sub", heartbeat_s=0, transport_options=TransportOptions(rcvhwm=HWM))
        node.subscribe("bench", Blob, counter.hit, queue_size=1)
        print("ready", flush=True)

        def poll() -> None:
            node.spin_once(0.05)

    while time.monotonic() < deadline and counter.count < args.n:
        poll()
        if counter.count:
            deadline = min(deadline, time.monotonic() + 60)
            if time.perf_counter() - counter.last > IDLE_S:
                break
    result = counter.result()
    result["gaps"] = None if args.kind.startswith("zmq") else node.counters()["bench"].gaps
    print(json.dumps(result), flush=True)


def role_pub(args: argparse.Namespace) -> None:
    if args.kind.startswith("zmq"):
        ctx, sock = _raw_socket(args, zmq.PUB, server=False)
        sock.connect(args.endpoint)
        time.sleep(1.0)  # a raw PUB cannot tell when the subscription has arrived (palpa's waits for it, below)
        enc = msgspec.msgpack.Encoder()
        t0 = time.perf_counter()
        for i in range(args.n):
            pace(i, t0, args.rate)
            sock.send_multipart([b"bench", enc.encode(make_msg(i))])
        sock.close(30_000)
        ctx.term()
        return
    node = palpa.Node(name="bench_pub", heartbeat_s=0, transport_options=TransportOptions(sndhwm=HWM))
    pub = node.publisher("bench", Blob, batch=1, direct=args.kind == "palpa-direct")
    if not pub.wait_for_subscribers(30):
        raise SystemExit("bench publisher: no subscriber after 30 s")
    t0 = time.perf_counter()
    for i in range(args.n):
        pace(i, t0, args.rate)
        pub.publish(make_msg(i))
        if i % 1000 == 0:
            node.spin_once(0)
    node.close(linger_s=30)


# ---------------------------------------------------------------- the run (root, outside the namespaces)
def run(hosts: Any, env: dict[str, str], kind: str, n: int, rate: float, keys: Path) -> dict[str, Any]:
    endpoint = f"tcp://{hosts.addr(3)}:{PORT}"
    common = ["--kind", kind, "--n", str(n), "--rate", str(rate), "--keys", str(keys)]
    sub = subprocess.Popen(hosts.cmd(3, sys.executable, __file__, "--role", "sub", "--endpoint", endpoint, *common),
                           env=env, stdout=subprocess.PIPE, text=True)
    assert sub.stdout is not None
    if sub.stdout.readline().strip() != "ready":
        raise SystemExit(f"{kind}: the subscriber did not start")
    pub = subprocess.Popen(hosts.cmd(2, sys.executable, __file__, "--role", "pub", "--endpoint",
                                     f"tcp://{hosts.addr(3)}:{PORT}", *common), env=env)
    out = sub.stdout.readline()
    sub.wait(30)
    pub.wait(60)
    result: dict[str, Any] = json.loads(out)
    return result


def summary(rounds: list[tuple[dict[str, Any], dict[str, Any]]]) -> dict[str, Any]:
    """One contender over the rounds: the median throughput, and the latency percentiles of every latency run's
    samples pooled."""
    rates = sorted(thr["msg_per_s"] for thr, _ in rounds)
    lat = sorted(x for _, run_ in rounds for x in run_["_lat"])
    return {"msg_per_s": rates[len(rates) // 2], "msg_per_s_rounds": rates,
            "lost": sum(thr["lost"] for thr, _ in rounds), "latency_lost": sum(r["lost"] for _, r in rounds),
            "p50_us": round(lat[len(lat) // 2] / 1e3, 1) if lat else None,
            "p99_us": round(lat[int(len(lat) * 0.99)] / 1e3, 1) if lat else None,
            "steal_ms": sum(r["steal_ms"] or 0 for _, r in rounds)}


def main_run(args: argparse.Namespace) -> None:
    from palpa.net.keys import create_key_pair
    from tests.netns import Hosts, why_no_netns

    why = why_no_netns()
    if why:
        raise SystemExit(f"bench/multihost.py: {why}")
    hosts = Hosts(3)
    import tempfile

    with tempfile.TemporaryDirectory(prefix="palpa-mh-") as tmp:
        keys, clients = Path(tmp) / "keys", Path(tmp) / "clients"
        clients.mkdir()
        create_key_pair(keys, "server")
        create_key_pair(keys, "node")
        (clients / "node.key").write_bytes((keys / "node.key").read_bytes())
        bus = None
        try:
            hosts.up()
            bus = subprocess.Popen(hosts.cmd(1, sys.executable, "-m", "palpa.cli.main", "bus", "--tcp",
                                             hosts.addr(1), "--hwm", str(HWM), "--curve-secret",
                                             str(keys / "server.key_secret"), "--curve-clients", str(clients)),
                                   stdout=subprocess.PIPE, text=True)
            assert bus.stdout is not None
            line = bus.stdout.readline()
            address = line.split("ready ", 1)[1].strip()
            env = {**os.environ, "PALPA_BUS": address, "PALPA_BUS_SERVER_KEY": str(keys / "server.key"),
                   "PALPA_CURVE_SECRET": str(keys / "node.key_secret")}
            kinds = args.kinds.split(",")
            runs: dict[str, list[tuple[dict[str, Any], dict[str, Any]]]] = {k: [] for k in kinds}
            for r in range(args.rounds):  # contenders take turns, so a noisy spell of the host hits them alike
                for kind in kinds:
                    thr = run(hosts, env, kind, args.n, 0.0, keys)
                    lat = run(hosts, env, kind, args.latency_n, 1000.0, keys)
                    runs[kind].append((thr, lat))
                    print(f"round {r + 1} {kind:<13} {thr['msg_per_s']:>9} msg/s (lost {thr['lost']}, gaps "
                          f"{thr['gaps']})   p50 {lat['p50_us']!s:>7} us   p99 {lat['p99_us']!s:>7} us", flush=True)
            figures = {kind: summary(rs) for kind, rs in runs.items()}
            for kind, f in figures.items():
                print(f"{kind:<13} median {f['msg_per_s']:>9} msg/s (lost {f['lost']})   p50 {f['p50_us']!s:>7} us"
                      f"   p99 {f['p99_us']!s:>7} us (latency runs lost {f['latency_lost']}, steal {f['steal_ms']} ms)")
        finally:
            if bus is not None:
                bus.terminate()
                bus.wait(10)
            hosts.down()
    base = figures["zmq-curve"]
    ratios: dict[str, dict[str, float]] = {k: {"throughput_vs_zmq_curve": round(f["msg_per_s"] / base["msg_per_s"], 3),
                  "p99_vs_zmq_curve": round(f["p99_us"] / base["p99_us"], 2)} for k, f in figures.items()}
    plain = figures["zmq"]
    ratios["curve_cost"] = {"throughput_curve_vs_plain": round(base["msg_per_s"] / plain["msg_per_s"], 3),
                            "p99_curve_vs_plain": round(base["p99_us"] / plain["p99_us"], 2)}
    for k, ratio in ratios.items():
        print(f"{k:<13} {ratio}")
    print(json.dumps({"figures": figures, "ratios": ratios}))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=50_000, help="messages in each throughput run")
    p.add_argument("--latency-n", type=int, default=3000, help="messages in each 1 kHz latency run")
    p.add_argument("--rounds", type=int, default=3, help="turns each contender takes")
    p.add_argument("--kinds", default="zmq,zmq-curve,palpa-direct,palpa-bus", help=argparse.SUPPRESS)
    p.add_argument("--role", choices=["sub", "pub"], help=argparse.SUPPRESS)
    p.add_argument("--kind", help=argparse.SUPPRESS)
    p.add_argument("--rate", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--endpoint", help=argparse.SUPPRESS)
    p.add_argument("--keys", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role == "sub":
        role_sub(args)
    elif args.role == "pub":
        role_pub(args)
    else:
        main_run(args)


if __name__ == "__main__":
    main()
