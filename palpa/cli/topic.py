"""``palpa topic list|echo|hz|pub``: look at and poke the running graph."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import msgspec
import yaml

from palpa.cli.common import add_bus_arg, bus_and_source, import_message_modules, message_from_yaml
from palpa.errors import BusError, PalpaError, RegistryError
from palpa.launch.validate import did_you_mean
from palpa.message import lookup
from palpa.net.wire import TopicStats
from palpa.node.node import Node, RawMessage
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("topic", help="list, echo, measure or publish topics")
    verbs = p.add_subparsers(dest="topic_verb", metavar="VERB", required=True)

    ls = verbs.add_parser("list", help="topics seen in node heartbeats, with types and publishers")
    ls.add_argument("--wait", type=float, default=WAIT_S, help=WAIT_HELP)
    add_bus_arg(ls)
    ls.set_defaults(func=run_list)

    echo = verbs.add_parser("echo", help="print messages on a topic")
    echo.add_argument("topic", help="topic name as on the bus, e.g. chatter (no leading slash)")
    echo.add_argument("--raw", action="store_true", help="print the envelope header and payload bytes")
    echo.add_argument("-n", "--count", type=int, default=0, help="stop after N messages")
    echo.add_argument("--timeout", type=float, default=0.0, help="give up after S seconds (0: never)")
    add_bus_arg(echo)
    echo.set_defaults(func=run_echo)

    hz = verbs.add_parser("hz", help="rate from publish stamps, gaps from sequence numbers")
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


WAIT_S = 1.5
WAIT_HELP = "seconds to listen for heartbeats (every node sends one a second; default %(default)s)"


def tool_node(args: argparse.Namespace, name: str) -> Node:
    """A heartbeat-less node on the verb's bus; ``args.bus_where`` names that bus and why it was chosen."""
    import_message_modules()
    address, source = bus_and_source(args)
    args.bus_where = f"{address} ({source})"
    return Node(name=f"_{name}_{int(time.time() * 1000) % 100000}", bus=address, heartbeat_s=0)


def bare_topic(topic: str) -> str:
    """Topic names on the bus have no leading slash (``/chatter`` is how ROS spells ``chatter``)."""
    if topic.startswith("/"):
        print(f"palpa topic: names on the bus have no leading slash: using {topic.lstrip('/')!r}", file=sys.stderr)
    return topic.lstrip("/")


def graph_topics(beats: dict[str, Heartbeat]) -> dict[str, dict[str, Any]]:
    """Topic -> {type, pub: [node], sub: [node]} from heartbeats (the runtime's own publications left out)."""
    topics: dict[str, dict[str, Any]] = {}
    for hb in beats.values():
        for topic, tname in hb.publishes.items():
            if topic.startswith("_palpa/"):
                continue
            entry = topics.setdefault(topic, {"type": tname, "pub": [], "sub": [], "types": set()})
            entry["pub"].append(hb.node + (" (direct)" if topic in hb.direct else ""))
            entry["types"].add(tname)
        for topic, tname in hb.subscribes.items():
            if topic.startswith("_palpa/"):  # runtime traffic (heartbeats, parameter services): palpa node list -v
                continue
            entry = topics.setdefault(topic, {"type": tname, "pub": [], "sub": [], "types": set()})
            entry["sub"].append(hb.node)
            if tname != "*":
                entry["types"].add(tname)
    return topics


class GraphWatch:
    """Heartbeats heard by a tool node while it does its job, to warn about a topic no node publishes."""

    def __init__(self, node: Node, args: argparse.Namespace, topic: str) -> None:
        self.beats: dict[str, Heartbeat] = {}
        self._topic, self._where = topic, args.bus_where
        self._check_at = time.monotonic() + WAIT_S
        if topic != HEARTBEAT_TOPIC:
            node.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda hb: self.beats.__setitem__(hb.node, hb))
        else:
            self._check_at = math.inf

    def check(self) -> None:
        """Once the listening window is over: say so on stderr if no node heard publishes the topic."""
        if time.monotonic() < self._check_at:
            return
        self._check_at = math.inf
        if not self.beats:
            print(f"palpa topic: no nodes heard in {WAIT_S:g} s on {self._where}; waiting anyway", file=sys.stderr)
            return
        topics = graph_topics(self.beats)
        if topics.get(self._topic, {}).get("pub"):
            return
        known = sorted(t for t, e in topics.items() if e["pub"])
        print(f"palpa topic: none of the {len(self.beats)} nodes heard publishes {self._topic!r}"
              f"{did_you_mean(self._topic, known)}; waiting anyway (palpa topic list shows what is published)",
              file=sys.stderr, flush=True)


def collect_heartbeats(node: Node, wait_s: float) -> dict[str, Heartbeat]:
    """Listen for ``wait_s`` seconds and return the latest heartbeat of every node (not of a node whose latest
    said it is leaving)."""
    sub = node.subscribe(HEARTBEAT_TOPIC, Heartbeat)
    seen: dict[str, Heartbeat] = {}
    deadline = time.monotonic() + wait_s
    while (remaining := deadline - time.monotonic()) > 0:
        hb = sub.next(remaining)
        if hb is not None:
            seen[hb.node] = hb
    return {name: hb for name, hb in seen.items() if hb.state != "leaving"}


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


def _to_builtins(raw: RawMessage) -> Any:
    try:
        cls = lookup(raw.header.type)
        return msgspec.to_builtins(msgspec.msgpack.decode(raw.payload, type=cls))
    except (RegistryError, msgspec.ValidationError, msgspec.DecodeError):
        return msgspec.msgpack.decode(raw.payload)  # unknown type: still readable


def run_echo(args: argparse.Namespace) -> int:
    count = 0
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else math.inf

    bus_and_source(args)  # which bus, said first
    topic = bare_topic(args.topic)

    def on_raw(raw: RawMessage) -> None:
        nonlocal count
        if raw.topic != topic:
            return
        count += 1
        if args.raw:
            print(json.dumps({"topic": raw.topic, "header": msgspec.to_builtins(raw.header),
                              "payload_hex": raw.payload.hex(), "blobs": [len(b) for b in raw.blobs]}))
        else:
            body = _to_builtins(raw)
            print(f"--- {raw.topic} [{raw.header.type}] seq={raw.header.seq} from {raw.header.node}")
            print(yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=120).rstrip())
        sys.stdout.flush()

    with tool_node(args, "echo") as node:
        node.subscribe_raw(topic, on_raw)
        watch = GraphWatch(node, args, topic)
        while (not args.count or count < args.count) and time.monotonic() < deadline:
            node.spin_once(0.1)
            if not count:
                watch.check()
    if args.count and count < args.count:
        raise PalpaError(f"{topic}: got {count} of {args.count} messages before the timeout")
    return 0


def run_hz(args: argparse.Namespace) -> int:
    stamps: list[int] = []
    stats = TopicStats()
    from palpa.net.wire import SequenceTracker

    tracker = SequenceTracker()
    started = time.monotonic()
    last_print = started

    bus_and_source(args)  # which bus, said first
    topic = bare_topic(args.topic)

    def on_raw(raw: RawMessage) -> None:
        if raw.topic != topic or raw.from_cache:
            return
        if tracker.observe(raw.topic, raw.header.node, raw.header.seq, stats):
            stamps.append(raw.header.stamp)
            del stamps[: -args.window]

    with tool_node(args, "hz") as node:
        node.subscribe_raw(topic, on_raw)
        watch = GraphWatch(node, args, topic)
        while not args.duration or time.monotonic() - started < args.duration:
            node.spin_once(0.1)
            if not stats.received:
                watch.check()
            if time.monotonic() - last_print >= 1.0:
                last_print = time.monotonic()
                print(hz_line(stamps, stats), flush=True)
    print(hz_line(stamps, stats), flush=True)
    return 0


def hz_line(stamps: list[int], stats: TopicStats) -> str:
    """One line of rate statistics from publish stamps (ns) and sequence counters."""
    if len(stamps) < 2:
        return f"no rate yet ({stats.received} received)"
    dts = [(b - a) / 1e9 for a, b in zip(stamps, stamps[1:], strict=False)]
    mean = sum(dts) / len(dts)
    std = math.sqrt(sum((d - mean) ** 2 for d in dts) / len(dts))
    rate = 1.0 / mean if mean > 0 else math.inf
    return (f"rate {rate:.2f} Hz  min {min(dts) * 1e3:.2f} ms  max {max(dts) * 1e3:.2f} ms  "
            f"std {std * 1e3:.2f} ms  window {len(stamps)}  received {stats.received}  gaps {stats.gaps}")


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
