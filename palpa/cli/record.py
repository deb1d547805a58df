"""``palpa record [-o FILE] [TOPIC_REGEX ...]``: record the bus to MCAP (a thin CLI over the Recorder node)."""

from __future__ import annotations

import argparse
import time

from palpa.cli.common import add_bus_arg, run_with_params
from palpa.record.recorder import Recorder
from palpa.record.writer import COMPRESSIONS


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record topics to an MCAP file (Ctrl-C finalises it)")
    p.add_argument("topics", nargs="*", metavar="TOPIC_REGEX",
                   help="regexes matched against whole topic names (default: all non-runtime topics)")
    p.add_argument("-o", "--output", help="output file (default: recording-<date>-<time>.mcap)")
    p.add_argument("--exclude", action="append", default=[], metavar="REGEX", help="skip matching topics")
    p.add_argument("--split-size", type=float, default=0.0, metavar="MB", help="start a new file every MB")
    p.add_argument("--split-duration", type=float, default=0.0, metavar="S", help="start a new file every S s")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--launch-file", default="", help="store this (resolved) launch file in the recording")
    p.add_argument("--compression", choices=COMPRESSIONS, default="zstd")
    p.add_argument("--fsync", action="store_true", help="fsync at every chunk (survives power loss)")
    p.add_argument("--name", default="recorder", help="node name (default: recorder)")
    add_bus_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    params = {
        "output": args.output or time.strftime("recording-%Y%m%d-%H%M%S.mcap"),
        "topics": args.topics,
        "exclude": args.exclude,
        "split_size_mb": args.split_size,
        "split_duration_s": args.split_duration,
        "force": args.force,
        "launch_file": args.launch_file,
        "compression": args.compression,
        "fsync": args.fsync,
    }
    return run_with_params(Recorder, params, args, "palpa record")
