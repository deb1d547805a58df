"""``palpa run MODULE:CLASS [node options]``: run any palpa node class as a process (what launch files use)."""

from __future__ import annotations

import argparse
import os
import sys

from palpa import env as palpa_env
from palpa.current import find_bus
from palpa.node.runner import node_arg_parser, run_node_code
from palpa.targets import load_node_class


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    options = node_arg_parser("palpa run MODULE:CLASS").format_help().partition("options:")[2]
    p = sub.add_parser(
        "run", help="run a node class: palpa run package.module:Class [-p k=v ...]",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run a palpa node class as a process. MODULE is imported as `python -m` would: from the "
                    "working directory first, then PYTHONPATH. Without --bus or $PALPA_BUS the node joins the "
                    "running launch's bus (else the default bus; with several launches running, give --bus).",
        epilog=f"node options (after MODULE:CLASS; `palpa run MODULE:CLASS --help` adds its parameters):{options}")
    p.add_argument("target", metavar="MODULE:CLASS", help="e.g. nodes.demo:Talker, or shouter:Shouter in its folder")
    p.add_argument("rest", nargs=argparse.REMAINDER, help="node options")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.insert(0, cwd)  # as `python -m` does: a node's own folder is importable
    cls = load_node_class(args.target)  # a TargetError is a PalpaError: the CLI prints it as one line
    rest = list(args.rest)
    named = any(a == "--bus" or a.startswith("--bus=") for a in rest) or palpa_env.get(palpa_env.BUS)
    if not named and not {"-h", "--help"} & set(rest):  # a launched node has $PALPA_BUS: nothing to choose or say
        address, source = find_bus()  # refuses to guess among several running launches
        print(f"palpa run: joining bus {address} ({source})", file=sys.stderr)
        rest = ["--bus", str(address), *rest]
    return run_node_code(cls, rest, prog=args.target)
