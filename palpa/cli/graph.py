"""``palpa graph [launch FILE [name:=value ...] | --run DIR] -o graph.png``: the graph as a picture (rqt_graph)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from palpa.cli.common import add_bus_arg, bus_and_source, import_message_modules
from palpa.errors import PalpaError
from palpa.graph import describe, graph_of_heartbeats, graph_of_plan, render
from palpa.node.node import Node

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "graph", help="draw the graph: nodes, topics, services (of a launch file, or of the running graph)",
        description="Draw the graph as a picture (.png, .svg or .pdf by -o's suffix). `palpa graph launch FILE "
                    "[name:=value ...]` draws what the file would run, from each node class's declared topics and "
                    "services, without starting anything; `palpa graph` (with --run DIR or --bus) draws the "
                    "running graph from its nodes' heartbeats.")
    p.add_argument("source", nargs="*", metavar="launch FILE [name:=value ...]",
                   help="'launch' and a launch file with its args; nothing: the running graph")
    p.add_argument("-o", "--output", type=Path, required=True, help="the picture: graph.png, graph.svg, graph.pdf")
    p.add_argument("--wait", type=float, default=2.0, help="running graph: seconds to listen for heartbeats")
    add_bus_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from palpa.targets import load_node_class

    if args.source:
        if args.source[0] != "launch" or len(args.source) < 2:
            raise PalpaError(f"expected `palpa graph launch FILE [name:=value ...]`, got {' '.join(args.source)!r} "
                             "(nothing: the running graph)")
        from palpa.launch import load_launch, parse_overrides

        plan = load_launch(Path(args.source[1]), parse_overrides(args.source[2:]), run_dir=Path("runs/graph"))
        model = graph_of_plan(plan, load_node_class)
    else:
        import_message_modules()
        from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat

        address, where = bus_and_source(args)
        beats: dict[str, Heartbeat] = {}
        with Node(name=f"_graph_{int(time.time() * 1000) % 100000}", bus=address, heartbeat_s=0) as node:
            sub = node.subscribe(HEARTBEAT_TOPIC, Heartbeat)
            deadline = time.monotonic() + args.wait
            while (remaining := deadline - time.monotonic()) > 0:
                hb = sub.next(remaining)
                if hb is not None:
                    beats[hb.node] = hb
        if not beats:
            raise PalpaError(f"no node heartbeats heard in {args.wait:g} s on {address} ({where}): nothing to draw")
        model = graph_of_heartbeats(beats, f"running graph on {address} (heartbeats)")
    out = render(model, args.output)
    print(f"wrote {out}: " + "\n".join(describe(model)))
    return 0
