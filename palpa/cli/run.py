"""``palpa run MODULE:CLASS [node options]``: run any palpa node class as a process (what launch files use)."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from palpa import env as palpa_env
from palpa.current import read_current
from palpa.errors import PalpaError
from palpa.node.node import Node
from palpa.node.runner import node_arg_parser, run_node_code


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    options = node_arg_parser("palpa run MODULE:CLASS").format_help().partition("options:")[2]
    p = sub.add_parser(
        "run", help="run a node class: palpa run package.module:Class [-p k=v ...]",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run a palpa node class as a process. MODULE is imported as `python -m` would: from the "
                    "working directory first, then PYTHONPATH. Without --bus or $PALPA_BUS the node joins the "
                    "running launch's bus (else the default bus).",
        epilog=f"node options (after MODULE:CLASS; `palpa run MODULE:CLASS --help` adds its parameters):{options}")
    p.add_argument("target", metavar="MODULE:CLASS", help="e.g. nodes.demo:Talker, or shouter:Shouter in its folder")
    p.add_argument("rest", nargs=argparse.REMAINDER, help="node options")
    p.set_defaults(func=run)


def load_node_class(target: str) -> type[Node]:
    """Import ``package.module:Class`` and check it is a Node subclass; errors say what failed."""
    module_name, sep, class_name = target.partition(":")
    if not sep or not module_name or not class_name:
        raise PalpaError(f"{target!r}: expected package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        hint = (" (looked in the working directory and on PYTHONPATH)"
                if isinstance(exc, ModuleNotFoundError) and exc.name == module_name.split(".")[0] else "")
        raise PalpaError(f"{target!r}: cannot import {module_name!r}: {exc}{hint}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise PalpaError(f"{target!r}: module {module_name!r} has no {class_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise PalpaError(f"{target!r}: {class_name} is not a palpa.Node subclass")
    return cls


def run(args: argparse.Namespace) -> int:
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.insert(0, cwd)  # as `python -m` does: a node's own folder is importable
    cls = load_node_class(args.target)
    rest = list(args.rest)
    current = read_current()
    if current is not None and "--bus" not in rest and not palpa_env.get(palpa_env.BUS):
        print(f"palpa run: joining the running launch's bus ({current[1]})", file=sys.stderr)
        rest = ["--bus", current[0], *rest]
    return run_node_code(cls, rest, prog=args.target)
