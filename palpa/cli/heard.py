"""The running graph as a CLI tool hears it: a heartbeat-less tool node on the verb's bus, the heartbeats it
collects over a listening window, the topic table built from them (types, publishers, subscribers), and the watch
that warns while a verb waits on a topic no node publishes. Split from palpa.cli.topic; ``palpa node``,
``palpa param`` and ``palpa service`` use it too."""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

from palpa.cli.common import bus_and_source, import_message_modules
from palpa.launch.validate import did_you_mean
from palpa.node.node import Node
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat

__all__ = ["WAIT_HELP", "WAIT_S", "GraphWatch", "collect_heartbeats", "graph_topics", "tool_node"]

WAIT_S = 1.5
WAIT_HELP = "seconds to listen for heartbeats (every node sends one a second; default %(default)s)"


def tool_node(args: argparse.Namespace, name: str) -> Node:
    """A heartbeat-less node on the verb's bus; ``args.bus_where`` names that bus and why it was chosen."""
    import_message_modules()
    address, source = bus_and_source(args)
    args.bus_where = f"{address} ({source})"
    return Node(name=f"_{name}_{int(time.time() * 1000) % 100000}", bus=address, heartbeat_s=0)


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
