"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
from pathlib import Path
from typing import Any

from palpa.address import BusAddress
from palpa.current import find_bus
from palpa.node import Node
from palpa.runner import run_node_code

__all__ = ["add_bus_arg", "bus_address", "bus_and_source", "import_message_modules", "run_with_params"]


def add_bus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", help="bus address (default: --run's, else $PALPA_BUS, else the running launch's, "
                                 "else ipc:///tmp/palpa-<uid>)")
    p.add_argument("--run", type=Path, metavar="DIR",
                   help="use the bus of the launch running in DIR (e.g. runs/latest)")


def bus_and_source(args: argparse.Namespace) -> tuple[BusAddress, str]:
    """The bus the verb uses and where that came from (see palpa.current)."""
    return find_bus(getattr(args, "bus", None), getattr(args, "run", None))


def bus_address(args: argparse.Namespace) -> BusAddress:
    return bus_and_source(args)[0]


def import_message_modules() -> None:
    """Import the message packages so their types are in the registry (``PALPA_MESSAGES`` adds more,
    comma-separated module names)."""
    names = ["messages", *filter(None, os.environ.get("PALPA_MESSAGES", "").split(","))]
    for name in names:
        with contextlib.suppress(ImportError):
            importlib.import_module(name.strip())


def run_with_params(cls: type[Node], params: dict[str, Any], args: argparse.Namespace, prog: str) -> int:
    """Run a node class in this process as ``palpa run`` would, with the verb's options as its parameters."""
    argv = ["--name", args.name, "--params-json", json.dumps(params), "--bus", str(bus_address(args))]
    if getattr(args, "debug", False):
        argv.append("--debug")
    return run_node_code(cls, argv, prog=prog)
