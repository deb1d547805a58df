"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import time
from pathlib import Path
from typing import Any

import msgspec

from palpa import env as palpa_env
from palpa.current import find_bus
from palpa.errors import PalpaError
from palpa.launch.validate import did_you_mean
from palpa.message import Message, lookup
from palpa.net.address import BusAddress
from palpa.node.node import Node
from palpa.node.runner import run_node_code
from yamlstruct import Source, YamlError

__all__ = ["add_bus_arg", "bus_address", "bus_and_source", "import_message_modules", "message_from_yaml",
           "run_with_params"]


def add_bus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", help="bus address (default: --run's, else $PALPA_BUS, else the running launch's, "
                                 "else ipc://$XDG_RUNTIME_DIR/palpa/bus or ipc:///tmp/palpa-<uid>/bus)")
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
    for name in ["messages", *palpa_env.listed(palpa_env.MESSAGES)]:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)


def message_from_yaml(type_name: str, text: str, what: str = "data", *, stamp: bool = True) -> Message:
    """A message of type ``type_name`` from its fields written as YAML (``{text: hi}``). Unknown fields are
    refused, naming the closest declared one (a misspelt ``engaged: false`` must not send the default
    ``engaged: true``); with ``stamp``, a ``stamp_ns`` field left out is set to now. Errors name what was wrong
    (the field path for a bad value)."""
    import_message_modules()
    cls = lookup(type_name)
    try:
        fields = Source.from_text(text, what).data  # the one YAML reader: YAML 1.2 scalars, as in launch files
    except YamlError as exc:
        raise PalpaError(f"{what} is not valid YAML: {exc}") from None
    if fields is None:
        fields = {}
    if not isinstance(fields, dict):
        raise PalpaError(f"{type_name}: {what} must be a mapping of fields, e.g. '{{name: value}}', got {text!r}")
    declared = [f.name for f in msgspec.structs.fields(cls)]
    for key in fields:
        if key not in declared:
            raise PalpaError(f"{type_name} has no field {key!r}{did_you_mean(str(key), declared)}; its fields: "
                             f"{', '.join(declared)}")
    if stamp and "stamp_ns" in declared and "stamp_ns" not in fields:
        fields["stamp_ns"] = time.time_ns()
    try:
        return msgspec.convert(fields, cls)
    except msgspec.ValidationError as exc:
        raise PalpaError(f"{type_name}: {exc}") from None


def run_with_params(cls: type[Node], params: dict[str, Any], args: argparse.Namespace, prog: str) -> int:
    """Run a node class in this process as ``palpa run`` would, with the verb's options as its parameters."""
    argv = ["--name", args.name, "--params-json", json.dumps(params), "--bus", str(bus_address(args))]
    if getattr(args, "debug", False):
        argv.append("--debug")
    return run_node_code(cls, argv, prog=prog)
