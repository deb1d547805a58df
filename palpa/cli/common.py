"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import msgspec

from palpa.current import find_bus
from palpa.errors import PalpaError
from palpa.launch.validate import did_you_mean
from palpa.message import Message, lookup
from palpa.net.address import BusAddress
from palpa.node.node import Node
from palpa.node.runner import run_node_code
from palpa.targets import import_message_modules
from yamlstruct import Source, YamlError

__all__ = ["add_bus_arg", "bus_address", "bus_and_source", "import_message_modules", "message_from_yaml",
           "run_with_params"]


def add_bus_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bus", help="bus address (default: --run's, else $PALPA_BUS, else the one running launch's "
                                 "(with several running, say which), else ipc://$XDG_RUNTIME_DIR/palpa/bus or "
                                 "ipc:///tmp/palpa-<uid>/bus)")
    p.add_argument("--run", type=Path, metavar="RUN",
                   help="use the bus of the launch running in this run directory (e.g. runs/latest), or of the "
                        "running launch whose run directory has this name")


def bus_and_source(args: argparse.Namespace) -> tuple[BusAddress, str]:
    """The bus the verb uses and where that came from (see palpa.current); the first time, says so on stderr
    (``palpa node: bus ... (the running launch in runs/x)``) before the verb does anything on it, unless the
    command line names it (``--bus``: the user typed it, and an expected failure stays one line)."""
    chosen: tuple[BusAddress, str] | None = getattr(args, "bus_chosen", None)
    if chosen is None:  # chosen once per command: the line said and the bus used are the same
        chosen = args.bus_chosen = find_bus(getattr(args, "bus", None), getattr(args, "run", None))
        if chosen[1] != "--bus":
            print(f"palpa {getattr(args, 'verb', None) or 'tool'}: bus {chosen[0]} ({chosen[1]})", file=sys.stderr,
                  flush=True)
    return chosen


def bus_address(args: argparse.Namespace) -> BusAddress:
    return bus_and_source(args)[0]


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
