"""``palpa node list|info``: the nodes of the running graph, from their heartbeats."""

from __future__ import annotations

import argparse
import sys

from palpa.cli.common import add_bus_arg
from palpa.cli.heard import WAIT_HELP, WAIT_S, collect_heartbeats, tool_node
from palpa.errors import PalpaError
from palpa.launch.validate import did_you_mean
from palpa.runtime_msgs import Heartbeat


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("node", help="list running nodes")
    verbs = p.add_subparsers(dest="node_verb", metavar="VERB", required=True)
    ls = verbs.add_parser("list", help="nodes heard on the bus, with pid and counters")
    ls.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
    ls.add_argument("-v", "--verbose", action="store_true", help="topics and counters too")
    add_bus_arg(ls)
    ls.set_defaults(func=run_list)
    info = verbs.add_parser("info", help="one node: publishers, subscribers, services, counters (ros2 node info)")
    info.add_argument("node")
    info.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
    add_bus_arg(info)
    info.set_defaults(func=run_info)


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


def node_info_lines(name: str, beats: dict[str, Heartbeat]) -> list[str]:
    """What ``node info`` prints: the node's process, then its publishers, subscribers and service servers, each
    with its type and counters (the runtime's own ``_palpa/...`` traffic left out, as ``node list -v`` shows it)."""
    hb = beats.get(name)
    if hb is None:
        raise PalpaError(f"no node {name!r} heard{did_you_mean(name, list(beats))} ({len(beats)} nodes heard: "
                         f"{', '.join(sorted(beats)) or 'none'})")
    lines = [name, f"  pid {hb.pid} on {hb.host}, up {hb.uptime_s:.0f} s, {hb.state}", "  Publishers:"]
    for topic, tname in sorted(hb.publishes.items()):
        if not topic.startswith("_palpa/"):
            direct = ", direct" if topic in hb.direct else ""
            lines.append(f"    {topic}: {tname}  (sent {hb.sent.get(topic, 0)}{direct})")
    lines.append("  Subscribers:")
    for topic, tname in sorted(hb.subscribes.items()):
        if not topic.startswith("_palpa/"):
            c = hb.counters.get(topic)
            extra = f"  (received {c.received}, gaps {c.gaps}, bad {c.decode_errors})" if c else ""
            lines.append(f"    {topic}: {tname}{extra}")
    lines.append("  Service Servers:")
    lines += [f"    {s}: {types}" for s, types in sorted(hb.services.items()) if not s.startswith("_palpa/")]
    if hb.refused:
        lines.append("  Refused:")
        lines += [f"    {kind}: {n}" for kind, n in sorted(hb.refused.items())]
    return lines


def run_info(args: argparse.Namespace) -> int:
    with tool_node(args, "node_info") as node:
        beats = collect_heartbeats(node, args.wait)
    print("\n".join(node_info_lines(args.node, beats)))
    return 0
