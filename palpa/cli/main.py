"""``palpa`` — the command line. One module per verb (ros2cli style); each exposes ``register(subparsers)``
which adds its parser and sets ``func(args) -> int``.

Expected failures (a :class:`palpa.PalpaError`) print one line and exit 1; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from palpa.errors import PalpaError
from palpa.exiting import exit_now

__all__ = ["cli", "main"]

# verb -> module under palpa.cli; modules that are missing (not yet built) are skipped
VERBS = ("bus", "topic", "node", "service", "param", "run", "launch", "record", "play", "bag", "keygen",
         "schema", "viz", "graph")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or with ``only`` a verb's parser alone (importing one verb's module instead of
    fourteen saves ~40 ms at every start, which a launch pays before its first node)."""
    ap = argparse.ArgumentParser(prog="palpa", description="a node graph for robotic palpation")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = ap.add_subparsers(dest="verb", metavar="VERB")
    for verb in VERBS if only is None else (only,):
        try:
            module = importlib.import_module(f"palpa.cli.{verb}")
        except ModuleNotFoundError as exc:
            if exc.name == f"palpa.cli.{verb}":
                continue
            raise
        module.register(sub)
    return ap


def _verb_of(argv: list[str]) -> str | None:
    """The verb ``argv`` names (its first word that is not an option), if it is one of ours; None otherwise (no
    verb, help, or a typo, which the whole parser answers with the list of verbs)."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in VERBS else None


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command line; its exit code."""
    return _run(argv)[0]


def cli() -> NoReturn:
    """The ``palpa`` program: :func:`main` on ``sys.argv``, then exit; a verb whose files are all closed when it
    returns (``set_defaults(fast_exit=True)``: ``launch``) exits without the interpreter's teardown
    (palpa.exiting), which a launch's user would otherwise wait for."""
    code, fast = _run(None)
    if fast:
        exit_now(code)
    sys.exit(code)


def _run(argv: Sequence[str] | None) -> tuple[int, bool]:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = build_parser(_verb_of(argv))
    args = ap.parse_args(argv)
    if not getattr(args, "func", None):
        ap.print_help()
        return 1, False
    debug = bool(getattr(args, "debug", False))
    fast = bool(getattr(args, "fast_exit", False))
    try:
        code: int = args.func(args)
        return code, fast
    except PalpaError as exc:
        if debug:
            raise
        print(f"palpa {args.verb}: {exc}", file=sys.stderr)
        return 1, fast
    except KeyboardInterrupt:
        return 130, fast


if __name__ == "__main__":
    cli()
