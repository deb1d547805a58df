"""``palpa bag info|recover|export|filter|cut|merge``: inspect, repair, convert and edit recordings offline."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from palpa.atomic import written_beside
from palpa.record.edit import rewrite
from palpa.record.export import export_json
from palpa.record.format import BagError, TopicFilter
from palpa.record.info import bag_info, format_info
from palpa.record.reader import resolve_bag_paths
from palpa.record.recover import recover
from palpa.record.table_export import AlignSpec, export_tables
from palpa.record.tables import read
from palpa.record.writer import lock_exclusive

TOPICS_HELP = ("topics to take: regular expressions matched against the whole name (runtime _palpa/... topics "
               "only when a pattern names them); default: every topic")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bag", help="inspect, recover, export, filter, cut or merge recordings")
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

    exp = verbs.add_parser(
        "export", help="tables for pandas/R/a spreadsheet (--format csv|parquet), or a JSON MCAP for viewers",
        description="--format csv|parquet -o DIR: one table per topic, fields flattened (docs/recording.md); with "
                    "--align TOPIC or --rate HZ, -o FILE: one table of every selected topic on that time base. "
                    "--json OUT: a JSON-encoded MCAP that Foxglove reads field by field.")
    exp.add_argument("files", nargs="+", metavar="FILE", help="a .mcap file, a split base name or a directory")
    how = exp.add_mutually_exclusive_group(required=True)
    how.add_argument("--json", type=Path, metavar="OUT", dest="json_out", help="output .mcap file (JSON-encoded)")
    how.add_argument("--format", choices=("csv", "parquet"), help="tables, written to -o")
    exp.add_argument("-o", "--output", type=Path, help="with --format: a directory (one file per topic), or the "
                                                       "file of the aligned table")
    exp.add_argument("--topics", nargs="+", default=[], metavar="REGEX", help=TOPICS_HELP)
    exp.add_argument("--exclude", nargs="+", default=[], metavar="REGEX", help="topics to leave out")
    grid = exp.add_mutually_exclusive_group()
    grid.add_argument("--align", metavar="TOPIC", help="one table: a row at each message of TOPIC")
    grid.add_argument("--rate", type=float, metavar="HZ", help="one table: a row every 1/HZ seconds")
    exp.add_argument("--method", choices=("nearest", "linear"), default="nearest",
                     help="aligned columns: the nearest sample (default) or linear interpolation of numbers")
    exp.add_argument("--tolerance", type=float, default=AlignSpec.tolerance_s, metavar="S",
                     help="aligned cells stay empty where the topic has no sample within S seconds "
                          "(default %(default)s)")
    exp.add_argument("--time", choices=("publish", "log"), default="publish",
                     help="the time base: publishers' stamps (default) or the recorder's receive times")
    exp.add_argument("--blobs", choices=("drop", "base64"), default="drop",
                     help="--json: blob frames dropped (default, noted in the output) or exported as base64")
    exp.add_argument("--force", action="store_true", help="overwrite an existing output")
    exp.set_defaults(func=run_export)

    edits = (("filter", "a new recording of the chosen topics", "FILE"),
             ("cut", "a new recording of a time range (--start/--end seconds from the first message)", "FILE"),
             ("merge", "one recording of several, interleaved by time", "RECORDING"))
    for verb, text, meta in edits:
        e = verbs.add_parser(verb, help=text, description=f"{text[0].upper()}{text[1:]}: payloads, sequence "
                             "numbers, times, schemas, metadata and attachments (the launch file) kept as recorded.")
        e.add_argument("files", nargs="+", metavar=meta,
                       help="a .mcap file, a split base name or a directory" + (" (each one recording)"
                                                                                 if verb == "merge" else ""))
        e.add_argument("-o", "--output", type=Path, required=True, help="the new .mcap file")
        e.add_argument("--topics", nargs="+", default=[], metavar="REGEX", help=TOPICS_HELP)
        e.add_argument("--exclude", nargs="+", default=[], metavar="REGEX", help="topics to leave out")
        e.add_argument("--start", type=float, metavar="S", help="keep from S seconds after the first message")
        e.add_argument("--end", type=float, metavar="S", help="keep up to S seconds after the first message")
        e.add_argument("--force", action="store_true", help="overwrite an existing output")
        e.set_defaults(func=run_edit, edit=verb)


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
            with written_beside(src) as tmp:  # a failed recovery leaves the file as it was, and no copy beside it
                report = recover(src, tmp, overwrite=True)
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
    paths = resolve_bag_paths(args.files)
    if args.json_out is not None:
        report = export_json(paths, args.json_out, blobs=args.blobs, overwrite=args.force)
        print(report.text())
        if not report.complete:
            print(f"palpa bag: {len(report.placeholders)} message(s) could not be exported as JSON (see above); the "
                  "rest were exported; exit status 1", file=sys.stderr)
            return 1
        return 0
    if args.output is None:
        raise BagError("--format needs -o OUT (a directory for one table per topic, a file with --align/--rate)")
    spec = None
    if args.align is not None or args.rate is not None:
        spec = AlignSpec(topic=args.align, rate_hz=args.rate, method=args.method, tolerance_s=args.tolerance,
                         time=args.time)
        if args.align is not None and args.topics and not TopicFilter(args.topics)(args.align):
            args.topics = [*args.topics, args.align]
    frames = read(paths, args.topics, exclude=args.exclude)
    table = export_tables(frames, args.output, args.format, spec=spec, overwrite=args.force,
                          source=", ".join(map(str, paths)))
    print(table.text())
    return 0


def run_edit(args: argparse.Namespace) -> int:
    if args.edit == "merge":
        if len(args.files) < 2:
            raise BagError("merge needs two recordings or more")
        recordings = [resolve_bag_paths(f) for f in args.files]
    else:
        recordings = [resolve_bag_paths(args.files)]
    if args.edit == "filter" and not (args.topics or args.exclude):
        raise BagError("filter needs --topics or --exclude (which topics to keep)")
    if args.edit == "cut" and args.start is None and args.end is None:
        raise BagError("cut needs --start or --end (seconds from the first message)")
    start_ns = end_ns = None
    if args.start is not None or args.end is not None:
        first = min(int(bag_info(r)["start_ns"]) for r in recordings)
        start_ns = None if args.start is None else first + int(args.start * 1e9)
        end_ns = None if args.end is None else first + int(args.end * 1e9)
    report = rewrite(recordings, args.output, topics=TopicFilter(args.topics, args.exclude), start_ns=start_ns,
                     end_ns=end_ns, operation=args.edit, overwrite=args.force)
    print(report.text())
    return 0
