"""``palpa topic list|info|type|echo|hz|bw|pub``: look at and poke the running graph.

What the verbs hear of the graph (the tool node, heartbeats, the topic table, the unpublished-topic watch) is in
:mod:`palpa.cli.heard`."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Any

import msgspec
import yaml

from palpa.cli.common import add_bus_arg, bus_and_source, import_message_modules, message_from_yaml
from palpa.cli.heard import (  # re-exported: they were defined here (palpa.cli.heard holds them now)
    WAIT_HELP,
    WAIT_S,
    GraphWatch,
    collect_heartbeats,
    graph_topics,
    tool_node,
)
from palpa.errors import BusError, DecodeError, PalpaError, RegistryError
from palpa.launch.validate import did_you_mean
from palpa.message import lookup
from palpa.net.wire import DECODE_ERRORS, SequenceTracker, TopicStats, decode_any
from palpa.node.node import Node, RawMessage
from palpa.runtime_msgs import Heartbeat


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("topic", help="list, echo, measure or publish topics")
    verbs = p.add_subparsers(dest="topic_verb", metavar="VERB", required=True)

    ls = verbs.add_parser("list", help="topics seen in node heartbeats, with types and publishers")
    ls.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
    add_bus_arg(ls)
    ls.set_defaults(func=run_list)

    info = verbs.add_parser("info", help="a topic's type, publishers and subscribers (from heartbeats)")
    info.add_argument("topic")
    info.add_argument("-v", "--verbose", action="store_true", help="each publisher and subscriber, with counters")
    typ = verbs.add_parser("type", help="the message type a topic carries (from heartbeats)")
    typ.add_argument("topic")
    for verb, fn in ((info, run_info), (typ, run_type)):
        verb.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
        add_bus_arg(verb)
        verb.set_defaults(func=fn)

    bw = verbs.add_parser("bw", help="bandwidth of a topic: bytes per wall second, message sizes")
    bw.add_argument("topic")
    bw.add_argument("--window", type=int, default=100, help="messages in the rolling window")
    bw.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: never)")
    add_bus_arg(bw)
    bw.set_defaults(func=run_bw)

    echo = verbs.add_parser("echo", help="print messages on a topic")
    echo.add_argument("topic", help="topic name as on the bus, e.g. chatter (no leading slash)")
    echo.add_argument("--raw", action="store_true", help="print the envelope header and payload bytes")
    echo.add_argument("-n", "--count", type=int, default=0, help="stop after N messages")
    echo.add_argument("--timeout", type=float, default=0.0, help="give up after S seconds (0: never)")
    add_bus_arg(echo)
    echo.set_defaults(func=run_echo)

    hz = verbs.add_parser("hz", help="rate from publish stamps (simulated or wall time, said on each line), gaps "
                                     "from sequence numbers")
    hz.add_argument("topic", help="topic name as on the bus (no leading slash)")
    hz.add_argument("--window", type=int, default=1000, help="stamps in the rolling window")
    hz.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: never)")
    add_bus_arg(hz)
    hz.set_defaults(func=run_hz)

    pub = verbs.add_parser("pub", help="publish a message given as YAML",
                           description="Publish a message. Unknown fields are refused; it fails when no bus "
                                       "answers, and warns when nothing subscribes or the graph's nodes use "
                                       f"another type on the topic (it listens {WAIT_S:g} s for heartbeats first).")
    pub.add_argument("topic")
    pub.add_argument("type", help="message type name, e.g. Text")
    pub.add_argument("data", help="fields as YAML, e.g. '{text: hi}'")
    pub.add_argument("--rate", type=float, default=0.0, help="repeat at HZ (0: once)")
    pub.add_argument("--count", type=int, default=0, help="with --rate: stop after N (0: never)")
    pub.add_argument("--latched", action="store_true", help="latch the message on the bus")
    add_bus_arg(pub)
    pub.set_defaults(func=run_pub)


def bare_topic(topic: str) -> str:
    """Topic names on the bus have no leading slash (``/chatter`` is how ROS spells ``chatter``)."""
    if topic.startswith("/"):
        print(f"palpa topic: names on the bus have no leading slash: using {topic.lstrip('/')!r}", file=sys.stderr)
    return topic.lstrip("/")


def run_list(args: argparse.Namespace) -> int:
    with tool_node(args, "topic_list") as node:
        beats = collect_heartbeats(node, args.wait)
    topics = graph_topics(beats)
    if not topics:
        print(f"no topics: no node heartbeats heard in {args.wait:g} s on {args.bus_where}", file=sys.stderr)
        return 1
    for topic in sorted(topics):
        e = topics[topic]
        print(f"{topic}  [{e['type']}]  pub: {', '.join(e['pub']) or '-'}  sub: {', '.join(e['sub']) or '-'}")
    return 0


def topic_info_lines(topic: str, beats: dict[str, Heartbeat], verbose: bool = False) -> list[str]:
    """What ``topic info`` prints (ros2 topic info): type, publisher and subscription counts, with -v each node.
    Raises :class:`PalpaError` naming close topics when no node heard publishes or subscribes to it."""
    entry = graph_topics(beats).get(topic)
    if entry is None:
        raise PalpaError(f"no node heard publishes or subscribes to {topic!r}"
                         f"{did_you_mean(topic, list(graph_topics(beats)))} ({len(beats)} nodes heard)")
    lines = [f"Type: {'/'.join(sorted(entry['types'])) or entry['type']}",
             f"Publisher count: {len(entry['pub'])}", f"Subscription count: {len(entry['sub'])}"]
    if verbose:
        for name in sorted(entry["pub"]):
            hb = beats[name.removesuffix(" (direct)")]
            lines.append(f"  publisher  {name}  pid {hb.pid} on {hb.host}  sent {hb.sent.get(topic, 0)}")
        for name in sorted(entry["sub"]):
            c = beats[name].counters.get(topic)
            extra = f"  received {c.received} gaps {c.gaps} bad {c.decode_errors}" if c else ""
            lines.append(f"  subscriber {name}  pid {beats[name].pid} on {beats[name].host}{extra}")
    return lines


def run_info(args: argparse.Namespace) -> int:
    topic = bare_topic(args.topic)
    with tool_node(args, "topic_info") as node:
        beats = collect_heartbeats(node, args.wait)
    print("\n".join(topic_info_lines(topic, beats, args.verbose)))
    return 0


def run_type(args: argparse.Namespace) -> int:
    topic = bare_topic(args.topic)
    with tool_node(args, "topic_type") as node:
        beats = collect_heartbeats(node, args.wait)
    print(topic_info_lines(topic, beats)[0].removeprefix("Type: "))
    return 0


def bw_line(sizes: list[tuple[int, int]]) -> str:
    """Bandwidth from (receive time ns, bytes) pairs: bytes per second of wall time over the window, with the
    message sizes (ros2 topic bw)."""
    if len(sizes) < 2:
        return f"no bandwidth yet ({len(sizes)} received)"
    span = (sizes[-1][0] - sizes[0][0]) / 1e9
    nbytes = [n for _, n in sizes]
    rate = sum(nbytes[1:]) / span if span > 0 else math.inf
    return (f"{_size(rate)}/s from {len(sizes)} messages (wall time)  mean {_size(sum(nbytes) / len(nbytes))}  "
            f"min {_size(min(nbytes))}  max {_size(max(nbytes))}")


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB"):
        if n < 1000 or unit == "MB":
            return f"{n:.2f} {unit}" if unit != "B" else f"{n:.0f} B"
        n /= 1000
    return f"{n:.2f} MB"


def run_bw(args: argparse.Namespace) -> int:
    topic = bare_topic(args.topic)
    sizes: list[tuple[int, int]] = []

    def on_raw(raw: RawMessage) -> None:
        if raw.topic == topic and not raw.from_cache:
            sizes.append((raw.recv_ns, len(raw.payload) + sum(map(len, raw.blobs))))
            del sizes[: -args.window]

    started = last_print = time.monotonic()
    with tool_node(args, "bw") as node:
        node.subscribe_raw(topic, on_raw)
        watch = GraphWatch(node, args, topic)
        while not args.duration or time.monotonic() - started < args.duration:
            node.spin_once(0.1)
            if not sizes:
                watch.check()
            if time.monotonic() - last_print >= 1.0:
                last_print = time.monotonic()
                print(bw_line(sizes), flush=True)
    print(bw_line(sizes), flush=True)
    return 0


def _to_builtins(raw: RawMessage) -> Any:
    try:
        cls = lookup(raw.header.type)
        return msgspec.to_builtins(msgspec.msgpack.decode(raw.payload, type=cls))
    except (RegistryError, *DECODE_ERRORS):
        pass
    try:
        return decode_any(raw.payload)  # unknown type: still readable
    except DecodeError as exc:
        return {"_undecodable": str(exc), "payload_bytes": len(raw.payload)}


def _silence_stdout() -> None:
    """Point stdout at /dev/null once its reader is gone, so that no later flush (at exit) fails again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # not a real file (a test's stand-in): nothing to redirect
        pass


def run_echo(args: argparse.Namespace) -> int:
    count = 0
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else math.inf

    bus_and_source(args)  # which bus, said first
    topic = bare_topic(args.topic)

    closed = False

    def on_raw(raw: RawMessage) -> None:
        nonlocal count, closed
        if raw.topic != topic or closed:
            return
        count += 1
        try:
            if args.raw:
                print(json.dumps({"topic": raw.topic, "header": msgspec.to_builtins(raw.header),
                                  "payload_hex": raw.payload.hex(), "blobs": [len(b) for b in raw.blobs]}))
            else:
                body = _to_builtins(raw)
                print(f"--- {raw.topic} [{raw.header.type}] seq={raw.header.seq} from {raw.header.node}")
                print(yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=120).rstrip())
            sys.stdout.flush()
        except BrokenPipeError:  # the reader went away (`| head`): done, as any CLI tool would be
            closed = True
            _silence_stdout()

    with tool_node(args, "echo") as node:
        node.subscribe_raw(topic, on_raw)
        watch = GraphWatch(node, args, topic)
        while (not args.count or count < args.count) and time.monotonic() < deadline and not closed:
            node.spin_once(0.1)
            if not count:
                watch.check()
    if closed:
        return 0
    if args.count and count < args.count:
        raise PalpaError(f"{topic}: got {count} of {args.count} messages before the timeout")
    return 0


def run_hz(args: argparse.Namespace) -> int:
    stamps: list[int] = []
    stats = TopicStats()
    tracker = SequenceTracker()
    base = {"simulated": 0, "wall": 0}
    started = time.monotonic()
    last_print = started

    bus_and_source(args)  # which bus, said first
    topic = bare_topic(args.topic)

    def on_raw(raw: RawMessage) -> None:
        if raw.topic != topic or raw.from_cache:
            return
        if tracker.observe(raw.topic, raw.header.node, raw.header.seq, stats, raw.header.inc):
            stamps.append(raw.header.stamp)
            del stamps[: -args.window]
            base["simulated" if raw.header.at else "wall"] += 1

    with tool_node(args, "hz") as node:
        node.subscribe_raw(topic, on_raw)
        watch = GraphWatch(node, args, topic)
        while not args.duration or time.monotonic() - started < args.duration:
            node.spin_once(0.1)
            if not stats.received:
                watch.check()
            if time.monotonic() - last_print >= 1.0:
                last_print = time.monotonic()
                print(hz_line(stamps, stats, time_base(base)), flush=True)
    print(hz_line(stamps, stats, time_base(base)), flush=True)
    return 0


def time_base(counts: dict[str, int]) -> str:
    """The clock ``topic hz`` measures by: the publishers' stamps are simulated time when the publisher follows a
    simulation clock (its envelopes carry the simulated instant, ``at``), else wall time (a replay re-stamps what
    it plays with the wall clock)."""
    if counts["simulated"] and counts["wall"]:
        return "mixed: simulated and wall stamps"
    return "simulated time" if counts["simulated"] else "wall time"


def hz_line(stamps: list[int], stats: TopicStats, base: str = "wall time") -> str:
    """One line of rate statistics from publish stamps (ns) on the clock ``base`` names, and the losses the
    sequence numbers show (gaps: numbers skipped; restarts: a publisher that started again)."""
    losses = f"gaps {stats.gaps}" + (f"  restarts {stats.restarts}" if stats.restarts else "")
    if len(stamps) < 2:
        return f"no rate yet ({stats.received} received, {losses})"
    dts = [(b - a) / 1e9 for a, b in zip(stamps, stamps[1:], strict=False)]
    mean = sum(dts) / len(dts)
    std = math.sqrt(sum((d - mean) ** 2 for d in dts) / len(dts))
    rate = 1.0 / mean if mean > 0 else math.inf
    return (f"rate {rate:.2f} Hz ({base})  min {min(dts) * 1e3:.2f} ms  max {max(dts) * 1e3:.2f} ms  "
            f"std {std * 1e3:.2f} ms  window {len(stamps)}  received {stats.received}  {losses} (by sequence number)")


def _check_graph(node: Node, topic: str, type_name: str, where: str) -> None:
    """Listen for heartbeats, then warn on stderr if the graph's nodes use another type on ``topic``."""
    beats = collect_heartbeats(node, WAIT_S)
    entry = graph_topics(beats).get(topic)
    other = sorted(entry["types"] - {type_name}) if entry else []
    if other and entry is not None:
        users = ", ".join(entry["pub"] + entry["sub"])
        print(f"palpa topic pub: warning: {topic!r} carries {', '.join(other)} in this graph ({users}), not "
              f"{type_name}: its subscribers will drop this message", file=sys.stderr)
    if not beats:
        print(f"palpa topic pub: warning: no nodes heard in {WAIT_S:g} s on {where}", file=sys.stderr)


def run_pub(args: argparse.Namespace) -> int:
    import_message_modules()
    msg = message_from_yaml(args.type, args.data)
    bus_and_source(args)  # which bus, said first
    topic = bare_topic(args.topic)
    with tool_node(args, "pub") as node:
        if not getattr(node.transport, "connected", True):
            raise BusError(f"no bus answered on {args.bus_where}: nothing was sent (is the launch running? "
                           "--bus or --run DIR choose another)")
        pub = node.publisher(topic, type(msg), latched=args.latched)
        _check_graph(node, topic, args.type, args.bus_where)
        if not pub.has_subscribers and not args.latched:
            print(f"palpa topic pub: warning: nothing subscribes to {topic!r} on {args.bus_where}: the message "
                  "goes nowhere", file=sys.stderr)
        sent = 0
        period = 1.0 / args.rate if args.rate > 0 else 0.0
        next_t = time.monotonic()
        while True:
            pub.publish(msg)
            sent += 1
            if not period or (args.count and sent >= args.count):
                break
            next_t += period
            while (wait := next_t - time.monotonic()) > 0:
                node.spin_once(min(wait, 0.1))
    return 0
