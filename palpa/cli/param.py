"""``palpa param list [NODE]|describe|get|set|dump|load NODE``: running nodes' parameters, through their parameter
services (``param list`` without a node lists every node heard on the bus, as ``ros2 param list``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import yaml

from palpa.cli.common import add_bus_arg
from palpa.cli.heard import WAIT_HELP, WAIT_S, collect_heartbeats, tool_node
from palpa.cli.service import call_service
from palpa.errors import PalpaError
from palpa.launch.validate import did_you_mean
from palpa.message import Message
from palpa.node.params import parse_param_value, read_params_file
from palpa.node.params_runtime import ParamGet, ParamSet, ParamValues, param_service

__all__ = ["register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("param", help="list, read, change or dump a running node's parameters")
    verbs = p.add_subparsers(dest="param_verb", metavar="VERB", required=True)
    ls = verbs.add_parser("list", help="parameters with type, default, current value and whether each may change "
                                       "at run time (no NODE: every node's)")
    ls.add_argument("node", nargs="?", help="a node name; none: every node heard on the bus")
    ls.add_argument("--wait", type=float, default=WAIT_S, help="without NODE: " + WAIT_HELP)
    desc = verbs.add_parser("describe", help="one parameter: type, default, bounds, what it is, current value, when "
                                             "it may change")
    desc.add_argument("node")
    desc.add_argument("name")
    get = verbs.add_parser("get", help="one parameter's value (YAML), then whether it may change at run time")
    get.add_argument("node")
    get.add_argument("name")
    set_ = verbs.add_parser("set", help="change one parameter the node applies at run time (VALUE is YAML: 20, 2.5, "
                                        "true, [1, 2]); others are refused")
    set_.add_argument("node")
    set_.add_argument("name")
    set_.add_argument("value")
    dump = verbs.add_parser("dump", help="all parameters as YAML a launch file's params: accepts")
    dump.add_argument("node")
    dump.add_argument("-o", "--output", type=Path, help="write to this file instead of stdout")
    load = verbs.add_parser("load", help="set every parameter a YAML mapping gives (what dump writes), at once")
    load.add_argument("node")
    load.add_argument("file", type=Path)
    for verb, fn in ((ls, run_list), (desc, run_describe), (get, run_get), (set_, run_set), (dump, run_dump), (load, run_load)):
        verb.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the node")
        add_bus_arg(verb)
        verb.set_defaults(func=fn)


def _ask(args: argparse.Namespace, verb: str, request: Message) -> ParamValues:
    with tool_node(args, f"param_{verb}") as node:
        reply = call_service(node, param_service(args.node, verb), request, wait_s=args.timeout,
                             timeout_s=args.timeout)
    if not isinstance(reply, ParamValues):
        raise PalpaError(f"node {args.node!r} answered {type(reply).__name__}, not ParamValues")
    return reply


def _value_of(got: ParamValues, node: str, name: str) -> Any:
    if name not in got.values:
        raise PalpaError(f"node {node!r} has no parameter {name!r}{did_you_mean(name, list(got.values))} "
                         f"(has: {', '.join(got.values)})")
    return got.values[name]


def _yaml(value: Any) -> str:
    return yaml.safe_dump(value, sort_keys=False, default_flow_style=None, width=120).rstrip()


_CHANGE_TEXT = {"run time": "changeable at run time", "launch": "fixed at launch",
                "safety limit": "safety limit, fixed at launch"}


def change_text(got: ParamValues, name: str) -> str:
    """When parameter ``name`` may change, in words (``param list``, ``param get``)."""
    rule = got.change.get(name)
    return _CHANGE_TEXT.get(rule, f"may change: {rule}") if rule else "run-time rule unknown (an older node)"


def _list_lines(got: ParamValues, indent: str = "") -> list[str]:
    return [f"{indent}{name}: {got.types.get(name, '?')}  (now {value!r}; {change_text(got, name)})"
            for name, value in got.values.items()]


def run_list(args: argparse.Namespace) -> int:
    if args.node is not None:
        print("\n".join(_list_lines(_ask(args, "get", ParamGet()))))
        return 0
    # every node: ask each one heard (a node without parameter services, such as a tool, is said so)
    with tool_node(args, "param_list") as node:
        beats = collect_heartbeats(node, args.wait)
        if not beats:
            raise PalpaError(f"no nodes heard in {args.wait:g} s on {args.bus_where}")
        failed = 0
        for name in sorted(beats):
            print(f"{name}:")
            try:
                got = call_service(node, param_service(name, "get"), ParamGet(), wait_s=args.timeout,
                                   timeout_s=args.timeout)
            except PalpaError as exc:
                failed += 1
                print(f"  (no answer: {exc})")
                continue
            if isinstance(got, ParamValues):
                print("\n".join(_list_lines(got, "  ")))
    return 1 if failed == len(beats) else 0


def run_describe(args: argparse.Namespace) -> int:
    got = _ask(args, "get", ParamGet())
    value = _value_of(got, args.node, args.name)
    tname, _, default = got.types.get(args.name, "?").partition(" = ")
    print(f"parameter {args.name} of node {args.node}")
    print(f"  type:        {tname}")
    print(f"  default:     {default or '?'}")
    print(f"  value now:   {value!r}")
    print(f"  changes:     {change_text(got, args.name)}")
    print(f"  description: {got.docs.get(args.name) or '(none written)'}")
    return 0


def run_get(args: argparse.Namespace) -> int:
    got = _ask(args, "get", ParamGet())
    print(_yaml(_value_of(got, args.node, args.name)).removesuffix("\n..."))
    print(f"# {change_text(got, args.name)}")  # a YAML comment: the output still reads as the value
    return 0


def run_set(args: argparse.Namespace) -> int:
    value = parse_param_value(args.value, "value")
    got = _ask(args, "set", ParamSet(values={args.name: value}))
    print(f"{args.node}: {args.name} = {got.values[args.name]!r}")
    return 0


def run_dump(args: argparse.Namespace) -> int:
    got = _ask(args, "get", ParamGet())
    text = f"# parameters of node {args.node} (paste under its params: in a launch file, or --params-file)\n"
    text += yaml.safe_dump(got.values, sort_keys=False, default_flow_style=False) if got.values else "{}\n"
    if args.output is not None:
        args.output.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


def run_load(args: argparse.Namespace) -> int:
    values = read_params_file(args.file, str(args.file))
    got = _ask(args, "set", ParamSet(values=values))
    print(f"{args.node}: " + ", ".join(f"{k} = {got.values[k]!r}" for k in values))
    return 0
