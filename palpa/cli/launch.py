"""``palpa launch FILE [name:=value ...]``: run a whole graph from a launch file (see docs/launch.md).

``--check`` validates only and prints the resolved graph; ``--schema`` prints the JSON Schema of launch files.
Errors read ``file:line:col: what was expected`` and exit 1 (a traceback only with ``--debug``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from palpa.errors import PalpaError
from palpa.launch import LaunchPlan, Supervisor, json_schema, load_launch, parse_overrides
from palpa.launch.plan import RECORDER_NAME


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("launch", help="run a graph from a launch file (or --check it)",
                       description="Run a graph from a YAML launch file: the bus, then the nodes; Ctrl-C stops "
                                   "them (SIGINT, then SIGTERM, then SIGKILL). Options may come before or after "
                                   "the file.")
    _add_options(p)
    # argparse cannot mix options into positionals that follow them, so everything from the file on is parsed
    # again by _parse_rest (options included)
    p.add_argument("rest", nargs=argparse.REMAINDER, metavar="FILE [name:=value ...]",
                   help="the launch file, then arg overrides (value parsed as YAML)")
    p.set_defaults(func=run, fast_exit=True)  # every file is closed when the launch returns


def _add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check", action="store_true", help="validate only and print the resolved graph")
    p.add_argument("--schema", action="store_true", help="print the JSON Schema of launch files and exit")
    p.add_argument("--run-dir", type=Path, help="where logs and the resolved file go (default runs/<timestamp>)")
    p.add_argument("--bus-address", metavar="ADDRESS",
                   help="bind the bus here instead (ipc:///path, tcp://HOST:PORT, or tcp://HOST for OS ports)")
    shown = p.add_mutually_exclusive_group()
    shown.add_argument("--progress", dest="progress", action="store_true", default=None,
                       help="show progress (the default when the file has a progress topic: a bar on a terminal, "
                            "plain lines every 5 %% otherwise)")
    shown.add_argument("--no-progress", dest="progress", action="store_false",
                       help="no progress view: every node line stays on screen")
    p.add_argument("--in-process", action="store_true", default=None,
                   help="run the simulated-clock nodes, clock and recorder in one process, as fast as the CPU "
                        "allows (as the file's in_process: true)")
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")


def _parse_rest(args: argparse.Namespace) -> argparse.Namespace:
    inner = argparse.ArgumentParser(prog="palpa launch", add_help=False)
    _add_options(inner)
    inner.add_argument("file", nargs="?", type=Path)
    inner.add_argument("overrides", nargs="*", metavar="name:=value")
    return inner.parse_intermixed_args(list(args.rest), namespace=args)


def run(args: argparse.Namespace) -> int:
    debug = bool(getattr(args, "debug", False))
    try:
        return _run(args)
    except PalpaError as exc:
        if debug:
            raise
        print(str(exc), file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    args = _parse_rest(args)
    if args.schema:
        print(json.dumps(json_schema(), indent=2))
        return 0
    if args.file is None:
        raise PalpaError("palpa launch: give a launch file (or --schema)")
    overrides = parse_overrides(list(args.overrides))
    if args.check:
        plan = _composed(load_launch(args.file, overrides, run_dir=args.run_dir), args.in_process)
        print(describe(plan))
        return 0
    run_dir, created = _make_run_dir(args.run_dir)
    try:
        plan = _composed(load_launch(args.file, overrides, run_dir=run_dir, defer_node_checks=True), args.in_process)
    except PalpaError:
        if created:
            with contextlib.suppress(OSError):
                run_dir.rmdir()
        raise
    return Supervisor(plan, bus_address=args.bus_address, progress=args.progress, announce=True).run()


def _composed(plan: LaunchPlan, flag: bool | None) -> LaunchPlan:
    """The plan with its simulated-clock nodes composed in one process, when the flag or the file asks for it.
    A composed plan keeps the loader's deferred node checks for the launch to run while the composition imports
    its code (palpa.startgate); any other plan runs them here."""
    from palpa.launch.compose import compose_plan

    if flag or plan.in_process:
        return compose_plan(plan)
    checks, plan.pending_checks = plan.pending_checks, None
    if checks is not None:
        checks()
    return plan


def _make_run_dir(chosen: Path | None) -> tuple[Path, bool]:
    """``chosen`` (created if missing), or a new ``runs/<YYYYmmdd-HHMMSS>[-n]``; True if we created it."""
    if chosen is not None:
        existed = chosen.is_dir()
        chosen.mkdir(parents=True, exist_ok=True)
        return chosen, not existed
    base = Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    base.parent.mkdir(parents=True, exist_ok=True)
    for n in range(1000):
        path = base if n == 0 else base.with_name(f"{base.name}-{n}")
        try:
            path.mkdir()
            return path, True
        except FileExistsError:
            continue
    raise PalpaError(f"cannot make a fresh run directory next to {base}")


def _topics_of(spec: Any) -> dict[str, list[str]] | str:
    from palpa.launch.topics import declared_topics
    from palpa.targets import load_node_class

    try:
        return declared_topics(load_node_class(spec.target), spec.namespace, spec.remap)
    except PalpaError as exc:  # the loader already checked the import; be safe anyway
        return f"unknown ({exc})"


def describe(plan: LaunchPlan) -> str:
    """The resolved graph in readable YAML (what ``--check`` prints)."""
    doc: dict[str, Any] = {}
    if plan.description:
        doc["description"] = plan.description
    doc["files"] = list(plan.files)
    doc["args"] = dict(plan.args)
    if plan.included_args:
        doc["args set in included files by the command line"] = dict(plan.included_args)
    if plan.python_path:
        doc["python_path"] = list(plan.python_path)
    bus = plan.bus
    doc["bus"] = {
        "transport": bus.transport,
        "endpoint": bus.endpoint or ("a fresh ipc path per run" if bus.transport == "ipc"
                                     else "tcp://127.0.0.1, ports chosen by the OS"),
        "latched": list(bus.latched), "hwm": bus.hwm,
    }
    rec = plan.recorder()
    if rec is not None:
        doc["record"] = {"node": f"{RECORDER_NAME} ({rec.target})", "params": rec.params}
        if not plan.recorder_available:
            doc["record"]["note"] = "the recorder is not importable here: launching this file will fail"
    if plan.progress_topic:
        doc["progress"] = {"topic": plan.progress_topic}
    nodes: dict[str, Any] = {}
    for spec in plan.nodes:
        entry: dict[str, Any] = {"run": spec.target if spec.target else list(spec.cmd or [])}
        if spec.namespace:
            entry["namespace"] = spec.namespace
        entry["params"] = plan.node_params.get(spec.name, spec.params)
        if spec.target and spec.params:
            entry["set here"] = sorted(spec.params)
        for key in ("remap", "env"):
            if getattr(spec, key):
                entry[key] = getattr(spec, key)
        if spec.target:
            entry["topics"] = _topics_of(spec)
        flags = [f for f in ("required", "respawn") if getattr(spec, f)]
        if spec.respawn:
            flags.append(f"respawn_delay {spec.respawn_delay:g} s, max retries {spec.respawn_max_retries}")
        if flags:
            entry["flags"] = flags
        entry["stop"] = (f"SIGINT, SIGTERM after {spec.sigterm_timeout:g} s, SIGKILL after "
                         f"{spec.sigkill_timeout:g} s more")
        entry["output"] = spec.output
        entry["from"] = spec.where
        nodes[spec.name] = entry
    doc["nodes"] = nodes
    head = f"{plan.files[0] if plan.files else plan.file}: ok ({len(plan.nodes)} nodes)\n"
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120).rstrip()
