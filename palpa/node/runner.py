"""Running a node as a process: command-line parameters, signals, exit codes.

``run_node(MyNode)`` is a node's whole ``main()``. It accepts::

    --name NAME  --namespace NS  --bus ADDRESS  -p/--param KEY=VALUE (VALUE is YAML: 3, 2.5, true, [1, 2])
    --params-json JSON  --params-file FILE.yaml  --remap FROM:=TO  --sim-clock  --debug
    --sndhwm N  --rcvhwm N  --busy-poll-us US  --direct TOPIC   (transport options: palpa.net.transport)

SIGINT and SIGTERM ask the node to stop; it finishes its current callback, runs ``on_shutdown`` and closes its
sockets with a bounded linger. The process exits with ``node.exit_code`` (0 unless the node set it).
Either signal during start-up (a ``setup()`` still connecting to a robot, say) interrupts it: what setup opened
with ``Node.closing`` is closed, one line says so, and the process exits 128 + the signal's number (130, 143),
with no traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from types import FrameType
from typing import Any

from palpa.errors import PalpaError
from palpa.net.transport import TransportOptions
from palpa.node.node import Node
from palpa.node.params import (
    Params,
    change_rules,
    describe_params,
    parse_param_value,
    read_params_file,
)

__all__ = ["node_arg_parser", "params_from_args", "parse_remaps", "run_node", "run_node_code"]


def node_arg_parser(prog: str) -> argparse.ArgumentParser:
    """The command-line options every node understands."""
    ap = argparse.ArgumentParser(prog=prog, description=f"run the palpa node {prog}")
    ap.add_argument("--name", help="node name (default: from the class)")
    ap.add_argument("--namespace", default="", help="prefix for relative topic names")
    ap.add_argument("--bus", help="bus address (default: $PALPA_BUS or ipc://$XDG_RUNTIME_DIR/palpa/bus, else ipc:///tmp/palpa-<uid>/bus)")
    ap.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE",
                    help="set a parameter; VALUE is parsed as YAML (repeatable)")
    ap.add_argument("--params-json", help="all parameters as one JSON object (used by the launcher)")
    ap.add_argument("--params-file", type=Path, help="parameters from a YAML mapping")
    ap.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="rename a topic")
    ap.add_argument("--sim-clock", action="store_true", default=None,
                    help="follow simulation time on _palpa/clock (also PALPA_SIM_CLOCK=1)")
    ap.add_argument("--sndhwm", type=int, help="messages queued towards the bus before drops (default 10000; "
                                              "also in $PALPA_TRANSPORT)")
    ap.add_argument("--rcvhwm", type=int, help="messages queued from the bus before drops (default 10000; "
                                              "also in $PALPA_TRANSPORT)")
    ap.add_argument("--busy-poll-us", type=int, help="spin this long for input before blocking: lower latency "
                                                     "for a busy core (default 0, at most 1e6; also in $PALPA_TRANSPORT)")
    ap.add_argument("--direct", action="append", metavar="TOPIC",
                    help="publish TOPIC (as on the bus) straight to its subscribers, not through the proxy "
                         "(repeatable; also in $PALPA_TRANSPORT)")
    ap.add_argument("--debug", action="store_true", help="debug logging and tracebacks")
    return ap


def params_from_args(args: argparse.Namespace, params_type: type[Params] | None = None) -> dict[str, Any]:
    """Merge parameters: file, then JSON, then each -p in order (later wins). Given the node's ``params_type``,
    the file's names and values are checked at their ``file:line:col``."""
    params: dict[str, Any] = {}
    if args.params_file is not None:
        params.update(read_params_file(args.params_file, f"--params-file {args.params_file}", params_type))
    if args.params_json:
        try:
            loaded = json.loads(args.params_json)
        except json.JSONDecodeError as exc:
            raise PalpaError(f"--params-json: {exc}") from None
        if not isinstance(loaded, dict):
            raise PalpaError("--params-json: expected a JSON object")
        params.update(loaded)
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise PalpaError(f"--param {item!r}: expected KEY=VALUE")
        params[key] = parse_param_value(value, f"--param {key}")
    return params


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """``FROM:=TO`` items -> a remap table; a malformed item is a one-line error."""
    out = {}
    for item in items:
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            raise PalpaError(f"--remap {item!r}: expected FROM:=TO")
        out[src] = dst
    return out


class _Interrupted(BaseException):
    """SIGINT or SIGTERM while the node is being made (BaseException: no ``except Exception`` in a setup() may
    swallow it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def run_node(cls: type[Node], argv: Sequence[str] | None = None, *, prog: str | None = None) -> None:
    """Parse the command line, run the node until it stops or a signal arrives, and exit with its code."""
    sys.exit(run_node_code(cls, argv, prog=prog))


def run_node_code(cls: type[Node], argv: Sequence[str] | None = None, *, prog: str | None = None) -> int:
    """:func:`run_node` without the ``sys.exit``: returns the exit code."""
    ap = node_arg_parser(prog or cls.__name__)
    ap.formatter_class = argparse.RawDescriptionHelpFormatter
    declared, rules = describe_params(cls.Params), change_rules(cls.Params)
    marks = {"run time": "  [run-time changeable]", "safety limit": "  [safety limit]", "launch": ""}
    ap.epilog = "parameters (-p NAME=VALUE; fixed at launch unless marked run-time changeable):\n" + (
        "\n".join(f"  {k}: {v}{marks[rules[k]]}" for k, v in declared.items()) or "  none")
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )

    made: list[Node] = []

    def interrupt(signum: int, frame: FrameType | None) -> None:
        raise _Interrupted(signum)

    def stop(signum: int, frame: FrameType | None) -> None:
        made[0].request_shutdown()

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)
    try:
        made.append(cls(
            name=args.name,
            params=params_from_args(args, cls.Params),
            namespace=args.namespace,
            remap=parse_remaps(args.remap),
            bus=args.bus,
            sim_clock=args.sim_clock,
            transport_options=TransportOptions.from_env(
                sndhwm=args.sndhwm, rcvhwm=args.rcvhwm, busy_poll_us=args.busy_poll_us,
                direct=tuple(args.direct) if args.direct else None),
        ))
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)
    except PalpaError as exc:
        if args.debug:
            raise
        print(f"{prog or cls.__name__}: {exc}", file=sys.stderr)
        return 2
    except _Interrupted as exc:
        # Node.__init__ closed what setup() opened (it releases on any exception); a node made just before the
        # signal is closed here. Meanwhile a second SIGINT is ignored and a SIGTERM ends the process at once.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        for done in made:
            done.close()
        print(f"{prog or cls.__name__}: {signal.Signals(exc.signum).name} during start-up: stopped before running",
              file=sys.stderr)
        return 128 + exc.signum
    node = made[0]
    try:
        node.spin()
    finally:
        node.close()
    return node.exit_code
