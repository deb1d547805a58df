"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import time
from typing import Any

import msgspec
import yaml

from palpa.address import BusAddress, from_env
from palpa.errors import PalpaError
from palpa.message import Message, lookup
from palpa.node import Node
from palpa.runner import run_node_code

__all__ = ["add_bus_arg", "bus_address", "import_message_modules", "message_from_yaml", "run_with_params"]


def add_bus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", help="bus address (default: $PALPA_BUS or ipc:///tmp/palpa-<uid>)")


def bus_address(args: argparse.Namespace) -> BusAddress:
    return BusAddress.parse(args.bus) if getattr(args, "bus", None) else from_env()


def import_message_modules() -> None:
    """Import the message packages so their types are in the registry (``PALPA_MESSAGES`` adds more,
    comma-separated module names)."""
    names = ["messages", *filter(None, os.environ.get("PALPA_MESSAGES", "").split(","))]
    for name in names:
        with contextlib.suppress(ImportError):
            importlib.import_module(name.strip())


def message_from_yaml(type_name: str, text: str, what: str, *, stamp: bool = False) -> Message:
    """A message of type ``type_name`` from its fields written as YAML (``{text: hi}``); with ``stamp``, a
    ``stamp_ns`` field left out is set to now. Errors name what was wrong (the field path for a bad value)."""
    import_message_modules()
    cls = lookup(type_name)
    try:
        fields = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise PalpaError(f"{what} is not valid YAML: {exc}") from None
    fields = {} if fields is None else fields
    if stamp and isinstance(fields, dict) and "stamp_ns" not in fields and \
            "stamp_ns" in {f.name for f in msgspec.structs.fields(cls)}:
        fields["stamp_ns"] = time.time_ns()
    try:
        return msgspec.convert(fields, cls)
    except msgspec.ValidationError as exc:
        raise PalpaError(f"{type_name}: {exc}") from None


def run_with_params(cls: type[Node], params: dict[str, Any], args: argparse.Namespace, prog: str) -> int:
    """Run a node class in this process as ``palpa run`` would, with the verb's options as its parameters."""
    argv = ["--name", args.name, "--params-json", json.dumps(params)]
    if getattr(args, "bus", None):
        argv += ["--bus", args.bus]
    if getattr(args, "debug", False):
        argv.append("--debug")
    return run_node_code(cls, argv, prog=prog)
