"""``palpa bus``: run the graph's proxy and latched-value cache in the foreground."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path
from types import FrameType

from palpa.errors import BusError
from palpa.net.address import BusAddress, default_address
from palpa.net.bus import Bus, CurveServer
from palpa.net.latch import DEFAULT_LATCH_MAX_BYTES, DEFAULT_LATCH_MAX_ENTRIES
from palpa.net.wire import MAX_MSG_BYTES


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bus", help="run the bus (XSUB/XPUB proxy + latched cache)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--ipc", metavar="PATH", help="ipc base path (default: the private directory $XDG_RUNTIME_DIR/palpa or /tmp/palpa-<uid>, then /bus)")
    where.add_argument("--tcp", metavar="HOST[:PORT]",
                       help="tcp on HOST; PORT, PORT+1, PORT+2, or OS-chosen ports when PORT is omitted/0")
    where.add_argument("--address", help="an explicit address (any form palpa accepts)")
    p.add_argument("--latched", action="append", default=[], metavar="TOPIC",
                   help="cache this topic's last message for late joiners (repeatable)")
    p.add_argument("--hwm", type=int, default=10_000, help="high-water mark of the proxy sockets (messages)")
    p.add_argument("--max-msg-bytes", type=int, default=MAX_MSG_BYTES,
                   help="the largest frame accepted; a publisher sending more is disconnected (default 16 MiB)")
    p.add_argument("--latch-max-bytes", type=int, default=DEFAULT_LATCH_MAX_BYTES,
                   help="bytes the latched-value cache holds at most; later SETs are refused (default 64 MiB)")
    p.add_argument("--latch-max-entries", type=int, default=DEFAULT_LATCH_MAX_ENTRIES,
                   help="topics the latched-value cache holds at most (default 4096)")
    p.add_argument("--curve-secret", type=Path, help="the bus's CURVE secret key file (palpa keygen)")
    p.add_argument("--curve-clients", type=Path, help="folder of authorised client public key files")
    p.add_argument("--address-file", type=Path, help="also write the resolved address to this file")
    p.set_defaults(func=run)


def resolve_address(args: argparse.Namespace) -> BusAddress:
    if args.address:
        return BusAddress.parse(args.address)
    if args.tcp:
        host, sep, port = args.tcp.rpartition(":") if ":" in args.tcp else (args.tcp, "", "")
        if not sep or port in ("", "0", "*"):
            host = host or args.tcp
            return BusAddress(f"tcp://{host}:*", f"tcp://{host}:*", f"tcp://{host}:*")
        return BusAddress.parse(f"tcp://{host}:{port}")
    return BusAddress.parse(f"ipc://{args.ipc}" if args.ipc else default_address())


def run(args: argparse.Namespace) -> int:
    curve = None
    if args.curve_secret or args.curve_clients:
        if not (args.curve_secret and args.curve_clients):
            raise BusError("CURVE needs both --curve-secret and --curve-clients")
        curve = CurveServer(args.curve_secret, args.curve_clients)
    bus = Bus(resolve_address(args), latched_topics=args.latched, hwm=args.hwm, curve=curve,
              max_msg_bytes=args.max_msg_bytes, latch_max_bytes=args.latch_max_bytes,
              latch_max_entries=args.latch_max_entries)
    address = bus.start()
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    reload = threading.Event()
    if bus.clients is not None:  # SIGHUP: reread --curve-clients (a key added while the bus runs)
        signal.signal(signal.SIGHUP, lambda signum, frame: reload.set())
    if args.address_file:
        args.address_file.write_text(str(address) + "\n")
    # the ready line: launchers and tests wait for it
    print(f"palpa bus ready {address}", flush=True)
    try:
        while not stop.wait(0.2):
            if reload.is_set() and bus.clients is not None:
                reload.clear()
                try:
                    count = bus.clients.reload()
                except BusError as exc:
                    print(f"palpa bus: reload failed: {exc}", file=sys.stderr, flush=True)
                else:
                    print(f"palpa bus: reloaded {count} client key(s)", file=sys.stderr, flush=True)
    finally:
        bus.stop()
    print("palpa bus stopped", file=sys.stderr, flush=True)
    return 0
