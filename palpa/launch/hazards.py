"""Checks of a resolved launch plan for what would only fail (or be unsafe) at run time: a ``cmd`` program that
does not exist, a remap to a name no topic can have, a launcher bus listening beyond loopback without CURVE.
Each raises :class:`LaunchError` at the offending ``file:line:col``, so ``--check`` catches it. (Parameter bounds
come from the node's Params types, e.g. ``palpa.Positive``; non-finite timeouts from the launch schema.)
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Sequence
from pathlib import Path

from palpa.errors import BusError
from palpa.launch.plan import LaunchPlan, NodeSpec
from palpa.launch.source import Path_, Source
from palpa.net.bus import is_loopback_endpoint

__all__ = ["TOPIC_NAME", "check_bus_exposure", "check_cmd_program", "check_hazards", "check_remap"]

TOPIC_NAME = re.compile(r"^/?[A-Za-z0-9_][A-Za-z0-9_.-]*(/[A-Za-z0-9_][A-Za-z0-9_.-]*)*$")
"""A topic name: segments of letters, digits, '_', '-' and '.' separated by '/', optionally absolute ('/x')."""


def check_hazards(plan: LaunchPlan, top: Source | None, nodes: Sequence[tuple[Source, Path_, NodeSpec]]) -> None:
    """Every check of this module over a loaded plan."""
    for src, where, spec in nodes:
        check_cmd_program(src, where, spec)
        check_remap(src, where, spec)
    if top is not None:
        check_bus_exposure(plan, top)


def check_cmd_program(src: Source, where: Path_, spec: NodeSpec) -> None:
    """A ``cmd`` whose program is not found (on the node's PATH, or as a path) or cannot be executed."""
    if not spec.cmd:
        return
    program = spec.cmd[0]
    if "/" in program:
        path = Path(program)
        if not path.is_file():
            raise src.error((*where, "cmd", 0), f"node {spec.name!r}: cmd program {program!r}: no such file")
        if not os.access(path, os.X_OK):
            raise src.error((*where, "cmd", 0), f"node {spec.name!r}: cmd program {program!r} is not executable")
        return
    search = spec.env.get("PATH", os.environ.get("PATH", os.defpath))
    if shutil.which(program, path=search) is None:
        raise src.error((*where, "cmd", 0), f"node {spec.name!r}: cmd program {program!r} not found on PATH")


def check_remap(src: Source, where: Path_, spec: NodeSpec) -> None:
    """Remap entries must name topics: no spaces, wildcards or control characters."""
    for key, value in spec.remap.items():
        for name in (key, value):
            if not TOPIC_NAME.match(name):
                raise src.error((*where, "remap", key), f"node {spec.name!r}: remap {key!r} -> {value!r}: "
                                f"{name!r} is not a topic name (letters, digits, '_', '-', '.', separated "
                                "by '/')")


def check_bus_exposure(plan: LaunchPlan, top: Source) -> None:
    """The launcher's bus has no CURVE keys: it must not listen beyond loopback (the bus itself would refuse
    at run time; this says so at ``--check``)."""
    try:
        address = plan.bus_request()
    except BusError:
        return  # reported where the bus section is read
    for endpoint in (address.pub, address.sub, address.latch):
        if not is_loopback_endpoint(endpoint):
            raise top.error(("bus", "endpoint") if plan.bus.endpoint else ("bus",),
                            f"bus endpoint {endpoint} is beyond loopback, and the launcher's bus has no CURVE "
                            "keys: bind it to 127.0.0.1, or run `palpa bus --curve-secret ... --curve-clients "
                            "...` for other hosts (docs/wire.md)")
