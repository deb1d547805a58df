"""``palpa schema [TYPE ...]``: JSON Schema of message types (all registered ones by default); ``--list`` names
them (what ``ros2 interface list`` does)."""

from __future__ import annotations

import argparse
import json

from palpa.cli.common import import_message_modules
from palpa.errors import RegistryError
from palpa.launch.validate import did_you_mean
from palpa.message import json_schema, lookup, registered


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("schema", help="list message types, or print their JSON Schema",
                       description="Message types come from `messages` and the modules in $PALPA_MESSAGES "
                                   "(comma-separated; e.g. PALPA_MESSAGES=my_nodes.msgs for your own).")
    p.add_argument("types", nargs="*", help="type names (default: all)")
    p.add_argument("--list", action="store_true", help="only the type names, their modules and what they are")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import_message_modules()
    known = registered()
    if args.list:
        width = max(map(len, known), default=0)
        mod_width = max((len(c.__module__) for c in known.values()), default=0)
        for name in sorted(known):
            cls = known[name]
            doc = (cls.__doc__ or "").strip().splitlines()
            print(f"{name:<{width}}  {cls.__module__:<{mod_width}}  {doc[0] if doc else ''}")
        return 0
    for name in args.types:
        if name not in known:
            raise RegistryError(f"unknown message type {name!r}{did_you_mean(name, known)} "
                                "(palpa schema --list names them)")
    names = args.types or sorted(known)
    print(json.dumps({n: json_schema(lookup(n)) for n in names}, indent=2))
    return 0
