"""``palpa bag info|recover|export``: inspect, repair and convert recordings offline."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from palpa.record.export import export_json
from palpa.record.format import BagError
from palpa.record.info import bag_info, format_info
from palpa.record.reader import resolve_bag_paths
from palpa.record.recover import recover
from palpa.record.writer import lock_exclusive


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bag", help="inspect, recover or export recordings")
    verbs = p.add_subparsers(dest="bag_verb", metavar="VERB", required=True)

    info = verbs.add_parser("info", help="duration, topics, types, counts, rates, drops, metadata")
    info.add_argument("files", nargs="+", metavar="FILE", help="a .mcap file, a split base name or a directory")
    info.add_argument("--json", action="store_true", help="print the facts as one JSON object")
    info.set_defaults(func=run_info)

    rec = verbs.add_parser("recover", help="rebuild a valid, indexed file from one whose recorder was killed")
    rec.add_argument("file", type=Path)
    rec.add_argument("-o", "--output", type=Path, help="default: <stem>.recovered.mcap next to FILE")
    rec.add_argument("--in-place", action="store_true", help="replace FILE by the recovered file")
    rec.add_argument("--force", action="store_true", help="overwrite an existing output")
    rec.set_defaults(func=run_recover)

    exp = verbs.add_parser("export", help="write a JSON-encoded MCAP that viewers (Foxglove) read field by field")
    exp.add_argument("files", nargs="+", metavar="FILE", help="a .mcap file, a split base name or a directory")
    exp.add_argument("--json", required=True, type=Path, metavar="OUT", dest="out", help="output .mcap file")
    exp.add_argument("--blobs", choices=("drop", "base64"), default="drop",
                     help="blob frames: drop them (default, noted in the output) or export them as base64")
    exp.add_argument("--force", action="store_true", help="overwrite an existing output")
    exp.set_defaults(func=run_export)


def run_info(args: argparse.Namespace) -> int:
    info = bag_info(resolve_bag_paths(args.files))
    if args.json:
        print(json.dumps(info, default=str))
    else:
        print(format_info(info))
    return 0


def run_recover(args: argparse.Namespace) -> int:
    src: Path = args.file
    if not src.is_file():
        raise BagError(f"{src}: no such file")
    if args.in_place:
        if args.output:
            raise BagError("--in-place and --output exclude each other")
        with open(src, "rb") as guard:  # held until the file is replaced: no recorder starts writing it meanwhile
            if not lock_exclusive(guard):
                raise BagError(f"{src} is in use: a recorder is still writing it (it holds the file's lock); "
                               "stop the recorder first, or recover a copy with -o OUT")
            tmp = src.with_name(src.name + ".recovering")
            report = recover(src, tmp, overwrite=True)
            os.replace(tmp, src)
        report.output = src
    else:
        with open(src, "rb") as probe:
            live = not lock_exclusive(probe)
        report = recover(src, args.output, overwrite=args.force)
        if live:
            print(f"palpa bag: {src} is still being written by a recorder: the copy holds what it had written so far",
                  file=sys.stderr)
    print(report.text())
    return 0


def run_export(args: argparse.Namespace) -> int:
    report = export_json(resolve_bag_paths(args.files), args.out, blobs=args.blobs, overwrite=args.force)
    print(report.text())
    if not report.complete:
        print(f"palpa bag: {len(report.placeholders)} message(s) could not be exported as JSON (see above); the rest "
              "were exported; exit status 1", file=sys.stderr)
        return 1
    return 0
