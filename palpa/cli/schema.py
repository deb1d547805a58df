"""``palpa schema [TYPE ...]``: JSON Schema of message types (all registered ones by default)."""

from __future__ import annotations

import argparse
import json

from palpa.cli.common import import_message_modules
from palpa.message import json_schema, lookup, registered


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("schema", help="print the JSON Schema of message types")
    p.add_argument("types", nargs="*", help="type names (default: all)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import_message_modules()
    names = args.types or sorted(registered())
    print(json.dumps({n: json_schema(lookup(n)) for n in names}, indent=2))
    return 0
