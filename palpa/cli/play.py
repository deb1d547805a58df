"""``palpa play FILE ...``: republish a recording with its original timing (a thin CLI over the Player node)."""

from __future__ import annotations

import argparse

from palpa.cli.common import add_bus_arg, run_with_params
from palpa.node.runner import parse_remaps
from palpa.record.player import Player


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("play", help="replay a recording onto the bus")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="a .mcap file, a split recording's base name, or a run directory")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1.0)")
    p.add_argument("--loop", action="store_true", help="start over at the end")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--topics", nargs="+", default=[], metavar="REGEX",
                   help="play only topics matching these regexes (whole name); put FILE before this option")
    p.add_argument("--exclude", action="append", default=[], metavar="REGEX", help="skip matching topics")
    p.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="publish FROM as TO")
    p.add_argument("--clock", action="store_true", help="publish the recording's time on _palpa/clock")
    p.add_argument("--clock-hz", type=float, default=1000.0, help="clock ticks per second (default 1000)")
    p.add_argument("--wait-for", nargs="+", default=[], metavar="NODE",
                   help="play only once these nodes' heartbeats are heard (bounded by 10 s)")
    p.add_argument("--realtime", action="store_true",
                   help="real-time scheduling while playing (needs root/CAP_SYS_NICE; steadier timing on a busy host)")
    p.add_argument("--name", default="player", help="node name (default: player)")
    add_bus_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    remap = parse_remaps(args.remap)
    params = {
        "file": args.files if len(args.files) > 1 else args.files[0],
        "rate": args.rate,
        "loop": args.loop,
        "start_offset_s": args.start_offset,
        "topics": args.topics,
        "exclude": args.exclude,
        "remap": remap,
        "clock": args.clock,
        "clock_hz": args.clock_hz,
        "realtime": args.realtime,
        "wait_for": args.wait_for,
    }
    return run_with_params(Player, params, args, "palpa play")
