"""Loading a launch file into a :class:`~palpa.launch.plan.LaunchPlan`: args, substitutions, includes, validation.

Order of work for each file: read the YAML with marks; validate and resolve ``args`` (given value, else default,
else an error); apply substitutions to everything else; validate the result against
:class:`~palpa.launch.schema.LaunchFile`; load includes (paths relative to the including file, cycles refused);
collect the nodes. When every file is in, each ``node:`` class is imported and its params are validated with
:func:`palpa.node.params.convert_params` (:mod:`palpa.launch.nodecheck`; a composed launch defers that to run while
its simulation imports the same classes). Every error reads ``file:line:col: what was expected``.

Substitutions are applied by :mod:`palpa.launch.subst`; validation errors are worded by
:mod:`palpa.launch.validate`.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from palpa.errors import BusError, LaunchError
from palpa.launch.compose import name_clock_participants
from palpa.launch.hazards import check_hazards
from palpa.launch.nodecheck import validate_nodes, validate_recorder
from palpa.launch.plan import RECORDER_NAME, VIZ_NAME, LaunchPlan, NodeSpec
from palpa.launch.schema import ArgDecl, IncludeDecl, LaunchFile, NodeDecl, RecordDecl, VizDecl
from palpa.launch.source import Mark, Path_, Source, display_path
from palpa.launch.subst import substitute
from palpa.launch.validate import convert, did_you_mean, kind
from palpa.net.address import is_loopback_host

__all__ = ["load_launch", "parse_overrides"]

_RESERVED_NAMES = {"launch"}


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``name:=value`` words from the command line -> {name: value}; values are YAML scalars (``3`` is an int,
    ``true`` a bool, ``[1, 2]`` a list)."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition(":=")
        if not sep or not name:
            raise LaunchError(f"argument {item!r}: expected name:=value")
        out[name] = _parse_value(text, f"argument {name}:=")
    return out


def _parse_value(text: str, where: str) -> Any:
    if not text.strip():
        return ""
    try:
        return Source.from_text(text, where).data
    except LaunchError as exc:
        raise LaunchError(f"{where}{text}: not a valid YAML value ({str(exc).partition(': ')[2]})") from None


@dataclass
class _Given:
    """Values handed to a file's args, and where they came from (for errors). ``inherited`` are the command line's
    values, which set the same-named args of every file that declares them unless its include sets them."""

    values: dict[str, Any]
    marks: dict[str, Mark | None]
    origin: str  # "the command line" or "the include at file:line:col"
    inherited: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Collected:
    plan: LaunchPlan
    top: Source | None = None
    node_sources: list[tuple[Source, Path_, NodeSpec]] = field(default_factory=list)
    names: dict[str, str] = field(default_factory=dict)
    stack: list[Path] = field(default_factory=list)
    set_by: dict[str, str] = field(default_factory=dict)
    """bus/record/progress -> the file whose setting is used (the top file's, else the first include's)."""
    args_of: dict[str, tuple[dict[str, Any], _Given]] = field(default_factory=dict)
    """File name -> its resolved args and what gave them (to name the arg behind a bad param)."""
    declared: dict[str, list[str]] = field(default_factory=dict)
    """File name -> the args it declares (a command-line arg must be declared by one of them)."""
    command_line: dict[str, Any] = field(default_factory=dict)
    from_command_line: dict[str, list[str]] = field(default_factory=dict)
    """Included file -> its args set by the command line (shown by ``--check``)."""
    used: set[str] = field(default_factory=set)
    """Command-line args some file took."""
    set_by_include: dict[str, str] = field(default_factory=dict)
    """Arg name -> the include that set it explicitly (where a command-line value would not reach)."""


def load_launch(file: str | Path, overrides: Mapping[str, Any] | None = None, *,
                run_dir: str | Path | None = None, defer_node_checks: bool = False) -> LaunchPlan:
    """Read, resolve and validate a launch file (and its includes). Raises :class:`LaunchError` naming
    ``file:line:col`` and what was expected. Nothing is started. ``overrides`` are arg values (native types, see
    :func:`parse_overrides`); ``run_dir`` is what ``$(run_dir)`` means (default ``runs/<YYYYmmdd-HHMMSS>``
    under the working directory). With ``defer_node_checks`` the checks that import node classes (their
    parameters, their input files: ~0.2 s) are left in :attr:`LaunchPlan.pending_checks` for the caller to run,
    with the same errors, while a composed simulation imports the same classes (palpa.startgate)."""
    path = Path(file)
    if not path.is_file():
        siblings = sorted(display_path(p) for p in path.parent.glob("*.yaml")) if path.parent.is_dir() else []
        raise LaunchError(f"{display_path(path)}: no such launch file{did_you_mean(display_path(path), siblings)}")
    if run_dir is None:  # what the run directory will be called (the supervisor makes it)
        run_dir = Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    plan = LaunchPlan(file=path.resolve(), run_dir=Path(os.path.abspath(run_dir)))
    given = _Given({}, {k: None for k in overrides or {}}, "the command line", dict(overrides or {}))
    col = _Collected(plan, command_line=dict(overrides or {}))
    _load_file(path.resolve(), given, "", col, top=True)
    _check_command_line(overrides or {}, col)
    plan.included_args = dict(col.from_command_line)
    names = [n.name for n in plan.nodes]
    for name in plan.progress_report:
        if name not in names:
            raise LaunchError(f"{col.set_by.get('progress', plan.file)}: progress report names node {name!r}, which "
                              f"is not in the graph{did_you_mean(name, names)}")
    viz = plan.viz_node()
    if viz is not None:
        plan.nodes.insert(0, viz)  # first, so that it hears every node's first messages
    if defer_node_checks:
        plan.recorder_available = True  # until the checks import it (a launch that cannot record then ends)

        def checks() -> None:
            validate_recorder(col, deferred=True)
            validate_nodes(col)

        plan.pending_checks = checks
    else:
        validate_recorder(col)
        validate_nodes(col)
    check_hazards(plan, col.top, col.node_sources)
    name_clock_participants(plan)
    return plan


# -- one file -----------------------------------------------------------------------------------------
def _load_file(path: Path, given: _Given, namespace: str, col: _Collected, *, top: bool) -> None:
    src = Source.read(path)
    if top:
        col.top = src
    col.plan.files.append(src.name)
    col.stack.append(path)
    if src.data is None:
        raise LaunchError(f"{src.name}:1:1: empty launch file: expected a mapping with 'nodes' (and optionally "
                          "args, include, bus, record, progress)")
    if not isinstance(src.data, dict):
        raise src.error((), f"a launch file is a mapping (nodes:, args:, ...), not a {kind(src.data)}")
    data: dict[str, Any] = dict(src.data)
    args = _resolve_args(src, data.pop("args", []), given, col)
    col.args_of[src.name] = (args, given)
    if top:
        col.plan.args = dict(args)
    subst = {k: substitute(src, v, (k,), args, col.plan.run_dir) for k, v in data.items()}
    decl = convert(src, subst, LaunchFile)

    # an included file's bus/record/progress/viz apply unless the including file set its own (the top file wins),
    # so a shipped scan can be included, with its recording and progress bar, next to one more node
    own = {k for k in ("bus", "record", "progress", "viz") if getattr(decl, k) is not None and k not in col.set_by}
    col.set_by.update(dict.fromkeys(own, src.name))
    if top:
        col.plan.description = decl.description
    col.plan.in_process = col.plan.in_process or decl.in_process  # any file read may ask for it
    if "bus" in own and decl.bus is not None:
        col.plan.bus = decl.bus
        try:
            col.plan.bus_request()
        except BusError as exc:
            raise src.error(("bus",), str(exc)) from None
    if "progress" in own and decl.progress is not None:
        col.plan.progress_topic = decl.progress.topic
        col.plan.progress_report = list(decl.progress.report)
        if not decl.progress.topic:
            raise src.error(("progress", "topic"), "progress topic must not be empty")
    if "record" in own:
        _record(src, decl, col.plan)
    if "viz" in own:
        _viz(src, decl, col.plan)
    for i, entry in enumerate(decl.python_path):
        p = Path(entry)
        p = (p if p.is_absolute() else path.parent / p).resolve()
        if not p.is_dir():
            raise src.error(("python_path", i), f"python_path entry {entry!r}: no such folder ({p})")
        if str(p) not in col.plan.python_path:
            col.plan.python_path.append(str(p))
    for i, inc in enumerate(decl.include):
        _include(src, i, inc, namespace, col)
    col.plan.prepare.extend(list(c) for c in decl.prepare)
    for i, nd in enumerate(decl.nodes):
        if not nd.if_:
            continue
        spec = _node_spec(src, i, nd, namespace, col)
        col.plan.nodes.append(spec)
        col.node_sources.append((src, ("nodes", i), spec))
    col.stack.pop()


def _record(src: Source, decl: LaunchFile, plan: LaunchPlan) -> None:
    rec = decl.record
    if rec is None or rec is False:
        return
    plan.record = RecordDecl() if rec is True else rec
    _check_regexes(src, "record", plan.record)


def _check_regexes(src: Source, section: str, decl: RecordDecl | VizDecl) -> None:
    for key in ("topics", "exclude"):
        for i, rx in enumerate(getattr(decl, key)):
            try:
                re.compile(rx)
            except re.error as exc:
                raise src.error((section, key, i), f"not a regular expression: {exc}") from None


def _viz(src: Source, decl: LaunchFile, plan: LaunchPlan) -> None:
    viz = VizDecl() if decl.viz is True else decl.viz
    if viz is None or viz is False or not viz.enabled:
        return
    if not viz.allow_remote and not is_loopback_host(viz.host):
        raise src.error(("viz", "host"), f"viz host {viz.host!r} is beyond loopback: the Foxglove protocol has "
                                         "no authentication; set allow_remote: true to mean it")
    _check_regexes(src, "viz", viz)
    plan.viz = viz


def _resolve_args(src: Source, raw: Any, given: _Given, col: _Collected) -> dict[str, Any]:
    decls = convert(src, raw, list[ArgDecl], ("args",))
    values: dict[str, Any] = {}
    declared: dict[str, int] = {}
    from_command_line: set[str] = set()
    for i, decl in enumerate(decls):
        if decl.name in declared:
            raise src.error(("args", i, "name"), f"arg {decl.name!r} is declared twice")
        declared[decl.name] = i
        if decl.name in given.values:
            values[decl.name] = given.values[decl.name]
        elif decl.name in given.inherited:
            values[decl.name] = given.inherited[decl.name]
            from_command_line.add(decl.name)
        elif decl.default is not msgspec.UNSET:
            values[decl.name] = substitute(src, decl.default, ("args", i, "default"), values, col.plan.run_dir)
        else:
            how = (f"pass {decl.name}:=VALUE" if given.origin == "the command line"
                   else f"add {decl.name}: VALUE to the include's args, or pass {decl.name}:=VALUE")
            raise src.error(("args", i), f"arg {decl.name!r} has no default and was not given by {given.origin} "
                                         f"({how})")
    col.declared[src.name] = list(declared)
    col.used.update(from_command_line)
    if from_command_line and given.origin != "the command line":
        col.from_command_line[src.name] = sorted(from_command_line)
    for name in given.values:
        if name not in declared:
            hint = did_you_mean(name, declared)
            names = ", ".join(declared) or "none"
            mark = given.marks.get(name)
            where = f"{mark}: " if mark is not None else f"{src.name}: "
            raise LaunchError(f"{where}unknown arg {name!r} given by {given.origin}{hint} "
                              f"(args of {src.name}: {names})")
    return values


def _check_command_line(overrides: Mapping[str, Any], col: _Collected) -> None:
    """Every command-line arg must have been taken by some file: one no file declares is a misspelling, and one
    that only included files declare whose includes set it themselves would be silently ignored."""
    every = list(dict.fromkeys(a for names in col.declared.values() for a in names))
    top = col.plan.files[0] if col.plan.files else str(col.plan.file)
    for name in overrides:
        if name in col.used:
            continue
        if name in every:
            raise LaunchError(f"{top}: arg {name!r} given by the command line reaches no file: the include at "
                              f"{col.set_by_include.get(name, '?')} sets it itself, which wins (declare {name!r} "
                              f"in {top} and pass it on as {name}: $(arg {name}) to make it settable)")
        files = "; ".join(f"{f}: {', '.join(a) or 'none'}" for f, a in col.declared.items())
        raise LaunchError(f"{top}: unknown arg {name!r} given by the command line{did_you_mean(name, every)} "
                          f"(no file declares it; args of {files})")


def _include(src: Source, i: int, inc: IncludeDecl, namespace: str, col: _Collected) -> None:
    target = Path(inc.file)
    target = (target if target.is_absolute() else src.path.parent / target).resolve()
    if not target.is_file():
        raise src.error(("include", i, "file"), f"included launch file {inc.file!r} does not exist ({target})")
    if target in col.stack:
        chain = " -> ".join(display_path(p) for p in [*col.stack[col.stack.index(target):], target])
        raise src.error(("include", i, "file"), f"include cycle: {chain}")
    marks = {k: src.mark(("include", i, "args", k), key=True) for k in inc.args}
    # the command line's args reach every file that declares them; this include's own args win (_resolve_args)
    for k in inc.args:
        col.set_by_include.setdefault(k, str(src.mark(("include", i, "args", k), key=True)))
    given = _Given(dict(inc.args), dict(marks), f"the include at {src.mark(('include', i))}",
                   dict(col.command_line))
    ns = "/".join(filter(None, [namespace.strip("/"), inc.namespace.strip("/")]))
    _load_file(target, given, ns, col, top=False)


def _node_spec(src: Source, i: int, nd: NodeDecl, namespace: str, col: _Collected) -> NodeSpec:
    where = ("nodes", i)
    if (nd.node is None) == (nd.cmd is None):
        what = "both" if nd.node is not None else "neither"
        raise src.error(where, f"node {nd.name!r} has {what} of 'node' and 'cmd': give exactly one "
                               "(node: package.module:Class, or cmd: [program, args...])")
    if nd.name in col.names:
        raise src.error((*where, "name"), f"duplicate node name {nd.name!r} (first at {col.names[nd.name]})")
    if nd.name in _RESERVED_NAMES:
        raise src.error((*where, "name"), f"node name {nd.name!r} is reserved (its log would clash with the "
                                          "launcher's own)")
    if nd.name == RECORDER_NAME and col.plan.record is not None:
        raise src.error((*where, "name"), "node name 'recorder' is taken by the record section's recorder")
    if nd.name == VIZ_NAME and col.plan.viz is not None:
        raise src.error((*where, "name"), "node name 'viz' is taken by the viz section's Foxglove bridge")
    col.names[nd.name] = str(src.mark(where))
    for key, value in nd.remap.items():
        if not key or not value:
            raise src.error((*where, "remap", key), "remap entries are topic: topic, both non-empty")
    try:
        json.dumps(nd.params, allow_nan=True)
    except (TypeError, ValueError) as exc:
        raise src.error((*where, "params"), f"params must be plain data: {exc}") from None
    ns = "/".join(filter(None, [namespace.strip("/"), nd.namespace.strip("/")]))
    return NodeSpec(
        name=nd.name, target=nd.node, cmd=list(nd.cmd) if nd.cmd is not None else None, params=dict(nd.params),
        remap=dict(nd.remap), namespace=ns, env=dict(nd.env), respawn=nd.respawn, respawn_delay=nd.respawn_delay,
        respawn_max_retries=nd.respawn_max_retries, required=nd.required, sigterm_timeout=nd.sigterm_timeout,
        sigkill_timeout=nd.sigkill_timeout, output=nd.output,
        transport=nd.transport, where=str(src.mark(where)),
    )
