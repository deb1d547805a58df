"""``palpa node list``: the nodes of the running graph, from their heartbeats."""

from __future__ import annotations

import argparse
import sys

from palpa.cli.common import add_bus_arg
from palpa.cli.topic import WAIT_HELP, WAIT_S, collect_heartbeats, tool_node


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("node", help="list running nodes")
    verbs = p.add_subparsers(dest="node_verb", metavar="VERB", required=True)
    ls = verbs.add_parser("list", help="nodes heard on the bus, with pid and counters")
    ls.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
    ls.add_argument("-v", "--verbose", action="store_true", help="topics and counters too")
    add_bus_arg(ls)
    ls.set_defaults(func=run_list)


def run_list(args: argparse.Namespace) -> int:
    with tool_node(args, "node_list") as node:
        beats = collect_heartbeats(node, args.wait)
    if not beats:
        print(f"no nodes heard in {args.wait:g} s on {args.bus_where}", file=sys.stderr)
        return 1
    for name in sorted(beats):
        hb = beats[name]
        errors = sum(c.decode_errors for c in hb.counters.values())
        gaps = sum(c.gaps for c in hb.counters.values())
        print(f"{name}  pid {hb.pid}  up {hb.uptime_s:.0f} s  {hb.state}  "
              f"pub {len(hb.publishes)}  sub {len(hb.subscribes)}  gaps {gaps}  bad {errors}")
        if args.verbose:
            for topic, tname in sorted(hb.publishes.items()):
                direct = " (direct)" if topic in hb.direct else ""
                print(f"    pub {topic} [{tname}] sent {hb.sent.get(topic, 0)}{direct}")
            for topic, tname in sorted(hb.subscribes.items()):
                c = hb.counters.get(topic)
                extra = f" received {c.received} gaps {c.gaps} bad {c.decode_errors}" if c else ""
                print(f"    sub {topic} [{tname}]{extra}")
    return 0
