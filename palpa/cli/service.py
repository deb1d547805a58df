"""``palpa service list|type|call``: the services of the running graph, and calling one from the shell."""

from __future__ import annotations

import argparse
import sys
from typing import Any

import msgspec
import yaml

from palpa.cli.common import add_bus_arg, message_from_yaml
from palpa.cli.heard import collect_heartbeats, tool_node
from palpa.errors import DecodeError, PalpaError
from palpa.message import Message, lookup
from palpa.net.wire import decode_any
from palpa.node.node import Node, RawMessage
from palpa.node.params_runtime import ParamGet  # noqa: F401  (registers the parameter messages for `call`)
from palpa.node.service_client import discover

__all__ = ["call_service", "register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("service", help="list or call services")
    verbs = p.add_subparsers(dest="service_verb", metavar="VERB", required=True)

    ls = verbs.add_parser("list", help="services announced in node heartbeats, with types and servers")
    ls.add_argument("--wait", type=float, default=1.5, help="seconds to listen for heartbeats")
    ls.add_argument("-a", "--all", action="store_true", help="also every node's parameter services")
    add_bus_arg(ls)
    ls.set_defaults(func=run_list)

    typ = verbs.add_parser("type", help="a service's request and response types (as its server announces them)")
    typ.add_argument("name", help="service name, e.g. map/save")
    typ.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the server to be found")
    add_bus_arg(typ)
    typ.set_defaults(func=run_type)

    call = verbs.add_parser("call", help="call a service with a request given as YAML; prints the response")
    call.add_argument("name", help="service name, e.g. scanner/probe_at")
    call.add_argument("type", help="request type name, e.g. ProbeAt")
    call.add_argument("data", nargs="?", default="{}", help="request fields as YAML, e.g. '{x_mm: 30, y_mm: 30}'")
    call.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the reply")
    call.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the server to be found")
    call.add_argument("--feedback", metavar="TOPIC",
                      help="while waiting, print each message on TOPIC (a long call's progress, e.g. "
                           "robot/scan_status for scanner/probe_at)")
    add_bus_arg(call)
    call.set_defaults(func=run_call)


def run_list(args: argparse.Namespace) -> int:
    with tool_node(args, "service_list") as node:
        beats = collect_heartbeats(node, args.wait)
    every = sorted((name, types, hb.node) for hb in beats.values() for name, types in hb.services.items())
    rows = [row for row in every if args.all or not row[0].startswith("_palpa/")]
    if not every:
        print("no services (no node heartbeat announced one; is the graph running on this bus?)", file=sys.stderr)
        return 1
    for name, types, server in rows:
        print(f"{name}  [{types}]  server: {server}")
    if hidden := len(every) - len(rows):
        print(f"({'and ' if rows else 'no services but '}{hidden} parameter services, _palpa/param/NODE/get|set: "
              "`palpa service list --all` lists them, `palpa param` uses them)")
    return 0


def run_type(args: argparse.Namespace) -> int:
    with tool_node(args, "service_type") as node:
        info = discover(node, args.name, args.wait)
    print(f"{info.request_type} -> {info.response_type}")
    return 0


def call_service(node: Node, name: str, request: Message, *, wait_s: float, timeout_s: float) -> Any:
    """Find ``name``'s server, check the request type against it, call it; returns the response."""
    info = discover(node, name, wait_s)
    if info.request_type != request.type_name:
        raise PalpaError(f"service {name!r} takes {info.request_type}, not {request.type_name}")
    client = node.client(name, type(request), lookup(info.response_type), timeout_s=timeout_s)
    client.wait_for_service(wait_s)
    return client.call(request)


def run_call(args: argparse.Namespace) -> int:
    request = message_from_yaml(args.type, args.data, "request")
    with tool_node(args, "service_call") as node:
        if args.feedback:
            node.subscribe_raw(args.feedback, lambda raw: _print_feedback(args.feedback, raw))
        response = call_service(node, args.name, request, wait_s=args.wait, timeout_s=args.timeout)
    print(f"--- {args.name} -> {response.type_name}")
    print(yaml.safe_dump(msgspec.to_builtins(response), sort_keys=False, default_flow_style=None, width=120).rstrip())
    return 0


def _print_feedback(topic: str, raw: RawMessage) -> None:
    if raw.topic == topic and not raw.from_cache:
        try:
            body = msgspec.to_builtins(decode_any(raw.payload))
        except DecodeError as exc:
            body = {"_undecodable": str(exc)}
        print(f"[{topic}] " + yaml.safe_dump(body, default_flow_style=True, width=1_000_000).strip(), flush=True)
