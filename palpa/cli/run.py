"""``palpa run MODULE:CLASS [node options]``: run any palpa node class as a process (what launch files use)."""

from __future__ import annotations

import argparse
import importlib

from palpa.errors import PalpaError
from palpa.node import Node
from palpa.runner import run_node_code


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="run a node class: palpa run package.module:Class [--param k=v ...]",
                       add_help=False)
    p.add_argument("target", help="package.module:Class")
    p.add_argument("rest", nargs=argparse.REMAINDER, help="node options (see palpa run X:Y --help)")
    p.set_defaults(func=run)


def load_node_class(target: str) -> type[Node]:
    """Import ``package.module:Class`` and check it is a Node subclass; errors say what failed."""
    module_name, sep, class_name = target.partition(":")
    if not sep or not module_name or not class_name:
        raise PalpaError(f"{target!r}: expected package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise PalpaError(f"{target!r}: cannot import {module_name!r}: {exc}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise PalpaError(f"{target!r}: module {module_name!r} has no {class_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise PalpaError(f"{target!r}: {class_name} is not a palpa.Node subclass")
    return cls


def run(args: argparse.Namespace) -> int:
    cls = load_node_class(args.target)
    return run_node_code(cls, args.rest, prog=args.target)
