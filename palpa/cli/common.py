"""Helpers shared by the CLI verbs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os

from palpa.address import BusAddress, from_env

__all__ = ["add_bus_arg", "bus_address", "import_message_modules"]


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
