"""The checks of a launch file that import node classes: each node's parameters converted by its class, the input
files they name, the recorder's settings. Every error reads ``file:line:col: what was expected``, at the parameter.

They import the node runtime (palpa.node, palpa.targets: ~50 ms, and each node's own modules), so they run last,
and a launcher that defers them (``load_launch(..., defer_node_checks=True)``) starts a composed simulation before
paying for any of it (palpa.startgate).
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import msgspec

from palpa.errors import LaunchError, ParamError
from palpa.launch.plan import RECORDER_TARGET, LaunchPlan, NodeSpec
from palpa.launch.source import Path_, Source
from palpa.launch.validate import did_you_mean, lower_first

if TYPE_CHECKING:
    from palpa.node.node import Node

__all__ = ["Collected", "validate_nodes", "validate_recorder"]


class Collected(Protocol):
    """What the loader collected from a launch file and its includes that the checks read."""

    @property
    def plan(self) -> LaunchPlan: ...

    @property
    def top(self) -> Source | None: ...

    @property
    def node_sources(self) -> Sequence[tuple[Source, Path_, NodeSpec]]:
        """Each node with the file and the place in it that declared it."""

    @property
    def args_of(self) -> Mapping[str, tuple[Mapping[str, Any], Any]]:
        """File name -> its resolved args and what gave them (``values``, ``marks``, ``inherited``, ``origin``)."""


def validate_nodes(col: Collected) -> None:
    """Import each node's class and convert its params (the plan keeps them); the input files they name must exist,
    or be made in the run directory by the run itself."""
    from palpa.node.params import convert_params, input_paths

    saved = list(sys.path)
    sys.path[:0] = [p for p in col.plan.python_path if p not in sys.path]
    try:
        for src, where, spec in col.node_sources:
            if spec.target is None:
                continue
            cls = _import_node_class(src, (*where, "node"), spec.target)
            try:
                params = convert_params(cls.Params, spec.params, where=f"node {spec.name!r}")
            except ParamError as exc:
                raise _param_error(src, (*where, "params"), spec, exc, col) from None
            for name, value in input_paths(params).items():
                # a file in the run directory is made by the run itself (a prepare step) before the node starts
                made_by_run = Path(value).resolve().is_relative_to(col.plan.run_dir.resolve())
                if not made_by_run and not Path(value).exists():
                    raise src.error((*where, "params", name), f"param {name!r} of node {spec.name!r}: "
                                                              f"{value!r} does not exist (from {Path.cwd()})"
                                                              f"{_arg_note(col, src, (*where, 'params', name))}")
            col.plan.node_params[spec.name] = msgspec.to_builtins(params)
    finally:
        sys.path[:] = saved


def validate_recorder(col: Collected, *, deferred: bool = False) -> None:
    """The recorder the ``record`` section asks for: importable here (else the plan says it is not available, or,
    ``deferred``, the launch that went ahead on it ends) and taking the section's settings."""
    rec = col.plan.recorder()
    if rec is None:
        return
    from palpa.node.params import convert_params
    from palpa.targets import TargetError, load_node_class

    try:
        cls = load_node_class(RECORDER_TARGET)
    except TargetError as exc:
        if deferred:  # the launch went ahead on the module being there: it cannot record
            raise LaunchError(f"{col.plan.file}: the file asks to record, but {RECORDER_TARGET} is not importable "
                              f"here: {exc.reason}") from None
        col.plan.recorder_available = False  # --check still passes; launching says so
        return
    col.plan.recorder_available = True
    src = col.top if col.top is not None else Source.read(col.plan.file)
    try:
        convert_params(cls.Params, rec.params, where="record")
    except ParamError as exc:
        raise src.error(("record",), f"the recorder does not accept these settings: {exc}") from None


def _import_node_class(src: Source, where: Path_, target: str) -> type[Node]:
    from palpa.targets import TargetError, load_node_class

    try:
        return load_node_class(target)
    except TargetError as exc:
        raise src.error(where, exc.reason) from None


def _arg_note(col: Collected, src: Source, path: Path_) -> str:
    """'; it comes from arg X = V, given by the command line' for a value written as ``$(arg X)``."""
    raw = src.get(path)
    names = re.findall(r"\$\(\s*arg\s+([^()\s]+)\s*\)", raw) if isinstance(raw, str) else []
    args, given = col.args_of.get(src.name, ({}, None))
    notes = []
    for name in dict.fromkeys(names):
        if given is not None and name in given.values:
            mark = given.marks.get(name)
            notes.append(f"arg {name!r} = {json.dumps(args.get(name))}, given by {given.origin}"
                         + (f" at {mark}" if mark is not None else f" ({name}:=...)"))
        elif given is not None and name in given.inherited:
            notes.append(f"arg {name!r} = {json.dumps(args.get(name))}, given by the command line ({name}:=...)")
        elif name in args:
            notes.append(f"arg {name!r} = {json.dumps(args.get(name))} (its default)")
    return f"; from {'; '.join(notes)}" if notes else ""


def _param_error(src: Source, where: Path_, spec: NodeSpec, exc: ParamError, col: Collected) -> LaunchError:
    """The launch file's error for a parameter the node refused, at the parameter's key or value."""
    name, declared = exc.param, exc.declared
    if exc.unknown:
        return src.error((*where, name), f"node {spec.name!r} ({spec.target}) has no parameter {name!r}"
                                         f"{did_you_mean(name, declared)}; declared: {', '.join(declared) or 'none'}",
                         key=True)
    if name:
        return src.error((*where, name), f"param {name!r} of node {spec.name!r}: {lower_first(exc.reason)}"
                                         f"{_arg_note(col, src, (*where, name))}")
    return src.error(where, f"params of node {spec.name!r}: {exc.reason or exc}")
