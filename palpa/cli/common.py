"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
from typing import Any

from palpa.address import BusAddress, from_env
from palpa.node import Node
from palpa.runner import run_node_code

__all__ = ["add_bus_arg", "bus_address", "import_message_modules", "run_with_params"]


def add_bus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", help="bus address (default: $PALPA_BUS or ipc://$XDG_RUNTIME_DIR/palpa/bus, else ipc:///tmp/palpa-<uid>/bus)")


def bus_address(args: argparse.Namespace) -> BusAddress:
    return BusAddress.parse(args.bus) if getattr(args, "bus", None) else from_env()


def import_message_modules() -> None:
    """Import the message packages so their types are in the registry (``PALPA_MESSAGES`` adds more,
    comma-separated module names)."""
    names = ["messages", *filter(None, os.environ.get("PALPA_MESSAGES", "").split(","))]
    for name in names:
        with contextlib.suppress(ImportError):
            importlib.import_module(name.strip())


def run_with_params(cls: type[Node], params: dict[str, Any], args: argparse.Namespace, prog: str) -> int:
    """Run a node class in this process as ``palpa run`` would, with the verb's options as its parameters."""
    argv = ["--name", args.name, "--params-json", json.dumps(params)]
    if getattr(args, "bus", None):
        argv += ["--bus", args.bus]
    if getattr(args, "debug", False):
        argv.append("--debug")
    return run_node_code(cls, argv, prog=prog)
