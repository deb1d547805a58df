"""``palpa viz [TOPIC_REGEX ...]``: serve the bus to the Foxglove app (a thin CLI over the Bridge node)."""

from __future__ import annotations

import argparse

from palpa.cli.common import add_bus_arg, run_with_params
from palpa.viz.bridge import Bridge


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("viz", help="serve the bus live to Foxglove (WebSocket, default ws://127.0.0.1:8765)")
    p.add_argument("topics", nargs="*", metavar="TOPIC_REGEX",
                   help="regexes matched against whole topic names (default: all non-runtime topics)")
    p.add_argument("--exclude", action="append", default=[], metavar="REGEX", help="skip matching topics")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: loopback)")
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0: the OS chooses)")
    p.add_argument("--allow-remote", action="store_true",
                   help="allow a --host beyond loopback (no authentication: anyone who reaches it sees the bus)")
    p.add_argument("--allow-publish", action="append", default=[], metavar="TOPIC",
                   help="a topic clients may publish, e.g. robot/estop (repeatable)")
    p.add_argument("--queue-size", type=int, default=10_000, help="bus-to-WebSocket queue (messages)")
    p.add_argument("--name", default="viz", help="node name (default: viz)")
    add_bus_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    params = {
        "topics": args.topics,
        "exclude": args.exclude,
        "host": args.host,
        "port": args.port,
        "allow_remote": args.allow_remote,
        "client_publish": args.allow_publish,
        "queue_size": args.queue_size,
    }
    return run_with_params(Bridge, params, args, "palpa viz")
