"""``palpa`` — the command line. One module per verb (ros2cli style); each exposes ``register(subparsers)``
which adds its parser and sets ``func(args) -> int``.

Expected failures (a :class:`palpa.PalpaError`) print one line and exit 1; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from palpa.errors import PalpaError

__all__ = ["main"]

# verb -> module under palpa.cli; modules that are missing (not yet built) are skipped
VERBS = ("bus", "topic", "node", "service", "param", "run", "launch", "record", "play", "bag", "keygen",
         "schema", "viz", "graph")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="palpa", description="a node graph for robotic palpation")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="verb", metavar="VERB")
    for verb in VERBS:
        try:
            module = importlib.import_module(f"palpa.cli.{verb}")
        except ModuleNotFoundError as exc:
            if exc.name == f"palpa.cli.{verb}":
                continue
            raise
        module.register(sub)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = build_parser()
    args = ap.parse_args(argv)
    if not getattr(args, "func", None):
        ap.print_help()
        return 1
    debug = bool(getattr(args, "debug", False))
    try:
        code: int = args.func(args)
        return code
    except PalpaError as exc:
        if debug:
            raise
        print(f"palpa {args.verb}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
