"""The graph as a picture (``palpa graph``, rqt_graph's job): nodes, topics and services, who publishes and who
subscribes, which topics go direct (past the proxy, palpa.net.direct).

:class:`GraphModel` is built from a launch plan without starting anything (each node class's declared topics and
services, read from its source by :mod:`palpa.launch.topics`; a ``cmd:`` entry is an opaque process) or from the
heartbeats of a running graph (what each node really publishes, subscribes to and serves). :func:`render` draws it
with networkx and matplotlib: left to right in the direction data flows, processes as filled boxes, topics as
white boxes labelled with their type when known, services as yellow boxes; direct topics' edges in bold orange.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from palpa.errors import PalpaError

if TYPE_CHECKING:
    from palpa.launch.plan import LaunchPlan
    from palpa.runtime_msgs import Heartbeat

__all__ = ["GraphModel", "graph_of_heartbeats", "graph_of_plan", "render"]

FORMATS = ("png", "svg", "pdf")


@dataclass
class GraphModel:
    """Processes, topics and services, and the edges between them."""

    title: str = ""
    nodes: dict[str, str] = field(default_factory=dict)
    """Node name -> what runs it (a class, a command, or the pid and host of a running node)."""
    topics: dict[str, str] = field(default_factory=dict)
    """Topic -> its type name ("" when not known)."""
    publishes: set[tuple[str, str]] = field(default_factory=set)
    subscribes: set[tuple[str, str]] = field(default_factory=set)
    """(node, topic) pairs."""
    direct: set[str] = field(default_factory=set)
    """Topics sent straight to their subscribers (past the bus's proxy)."""
    services: dict[str, str] = field(default_factory=dict)
    """Service -> 'Request -> Response' ("" when not known)."""
    serves: set[tuple[str, str]] = field(default_factory=set)
    calls: set[tuple[str, str]] = field(default_factory=set)
    """(node, service) pairs."""

    def publish(self, node: str, topic: str, type_name: str = "") -> None:
        """``node`` publishes ``topic``."""
        self.topics[topic] = self.topics.get(topic) or type_name
        self.publishes.add((node, topic))

    def subscribe(self, node: str, topic: str, type_name: str = "") -> None:
        """``node`` subscribes to ``topic``."""
        self.topics[topic] = self.topics.get(topic) or ("" if type_name == "*" else type_name)
        self.subscribes.add((node, topic))

    def unheard(self) -> list[str]:
        """Topics subscribed to that no node of this graph publishes (fed from outside, or by nobody)."""
        published = {t for _, t in self.publishes}
        return sorted(t for t in self.topics if t not in published)


def graph_of_plan(plan: LaunchPlan, load_class: Any) -> GraphModel:
    """The graph a launch plan would run, from each node class's declared topics and services (nothing started).
    ``load_class(target)`` imports a ``module:Class``. The recorder and the Foxglove bridge, which take every topic,
    are shown without edges."""
    from palpa.launch.plan import RECORDER_TARGET, VIZ_TARGET
    from palpa.launch.topics import declared_services, declared_topics

    g = GraphModel(title=f"{plan.files[0] if plan.files else plan.file} (declared topics)")
    specs = list(plan.nodes)
    rec = plan.recorder()
    if rec is not None:
        specs.append(rec)
    for spec in specs:
        if spec.target is None:
            g.nodes[spec.name] = " ".join(spec.cmd or [])[:40]
            continue
        g.nodes[spec.name] = spec.target.rpartition(":")[2]
        if spec.target in (RECORDER_TARGET, VIZ_TARGET):
            g.nodes[spec.name] += " (takes every topic)"
            continue
        cls = load_class(spec.target)
        topics = declared_topics(cls, spec.namespace, spec.remap)
        for topic in topics["publishes"]:
            g.publish(spec.name, topic)
        for topic in topics["subscribes"]:
            g.subscribe(spec.name, topic)
        services = declared_services(cls, spec.namespace, spec.remap)
        for name in services["serves"]:
            g.services.setdefault(name, "")
            g.serves.add((spec.name, name))
        for name in services["calls"]:
            g.services.setdefault(name, "")
            g.calls.add((spec.name, name))
        if spec.transport is not None:
            g.direct.update(spec.transport.direct)
    return g


def graph_of_heartbeats(beats: Mapping[str, Heartbeat], title: str = "") -> GraphModel:
    """The running graph as its nodes' heartbeats describe it (runtime ``_palpa/...`` traffic left out)."""
    g = GraphModel(title=title)
    services = {s for hb in beats.values() for s in hb.services if not s.startswith("_palpa/")}

    def plumbing(topic: str) -> str | None:
        """The service whose request or reply topic this is (palpa.node.service), or None."""
        for s in services:
            if topic.rstrip("*") == f"{s}/request" or topic.startswith(f"{s}/reply/"):
                return s
        return None

    for name in sorted(beats):
        hb = beats[name]
        g.nodes[name] = f"pid {hb.pid} on {hb.host}"
        for topic, type_name in hb.publishes.items():
            if not topic.startswith("_palpa/") and plumbing(topic) is None:
                g.publish(name, topic, type_name)
        for topic, type_name in hb.subscribes.items():
            service = plumbing(topic)
            if service is not None and "/reply/" in topic:
                g.services.setdefault(service, "")
                g.calls.add((name, service))  # a caller hears its replies on <service>/reply/<caller>
            elif not topic.startswith("_palpa/") and service is None:
                g.subscribe(name, topic, type_name)
        g.direct.update(t for t in hb.direct if not t.startswith("_palpa/"))
        for service, types in hb.services.items():
            if not service.startswith("_palpa/"):
                g.services[service] = types
                g.serves.add((name, service))
    return g


# -- drawing ---------------------------------------------------------------------------------------------------
_NODE, _TOPIC, _SERVICE = "node", "topic", "service"


def _layers(graph: Any) -> dict[Any, int]:
    """A column for every vertex: the longest path to it from a source, after the edges that close a cycle are set
    aside (feedback loops, such as the scanner moving the arm whose pose the sensors read, would otherwise put
    the whole loop in one column). The cycles are broken by a depth-first walk from the sources, so the edge
    set aside is the one that returns upstream."""
    import networkx as nx

    acyclic = nx.DiGraph()
    acyclic.add_nodes_from(graph.nodes)
    state: dict[Any, int] = {}  # 1: on the walk's path, 2: done
    roots = sorted(graph.nodes, key=lambda v: (graph.in_degree(v) > 0, str(v)))
    for root in roots:
        if root in state:
            continue
        state[root] = 1
        stack = [(root, iter(sorted(graph.successors(root), key=str)))]
        while stack:
            v, children = stack[-1]
            child = next(children, None)
            if child is None:
                state[v] = 2
                stack.pop()
            elif state.get(child) == 1:
                continue  # back to a vertex on the path: the edge closes a cycle
            else:
                acyclic.add_edge(v, child)
                if child not in state:
                    state[child] = 1
                    stack.append((child, iter(sorted(graph.successors(child), key=str))))
    depth: dict[Any, int] = {}
    for v in nx.topological_sort(acyclic):
        depth[v] = max((depth[p] + 1 for p in acyclic.predecessors(v)), default=0)
    return depth


def _label(text: str, width: int = 22) -> str:
    """Long names broken at '/' so a box stays narrow."""
    if len(text) <= width:
        return text
    parts, line, lines = text.split("/"), "", []
    for p in parts:
        piece = (line + "/" if line else "") + p
        if len(piece) > width and line:
            lines.append(line + "/")
            line = p
        else:
            line = piece
    lines.append(line)
    return "\n".join(lines)


def render(g: GraphModel, output: str | Path) -> Path:
    """Draw ``g`` into ``output`` (.png, .svg or .pdf, by its suffix); returns the path."""
    out = Path(output)
    fmt = out.suffix.lstrip(".").lower()
    if fmt not in FORMATS:
        raise PalpaError(f"{out}: the picture's format comes from its suffix: .png, .svg or .pdf")
    if not g.nodes:
        raise PalpaError("the graph has no nodes: nothing to draw")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import networkx as nx
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    graph = nx.DiGraph()
    for n in g.nodes:
        graph.add_node(("n", n), kind=_NODE)
    for t in g.topics:
        graph.add_node(("t", t), kind=_TOPIC)
    for s in g.services:
        graph.add_node(("s", s), kind=_SERVICE)
    for n, t in g.publishes:
        graph.add_edge(("n", n), ("t", t), kind="pub")
    for n, t in g.subscribes:
        graph.add_edge(("t", t), ("n", n), kind="sub")
    layers = _layers(graph)  # of the data flow; a service sits in its server's column
    for n, s in g.serves:
        graph.add_edge(("n", n), ("s", s), kind="serve")
        layers[("s", s)] = layers[("n", n)]
    for n, s in g.calls:
        graph.add_edge(("n", n), ("s", s), kind="call")
        layers.setdefault(("s", s), layers[("n", n)] + 1)
    pos: dict[Any, tuple[float, float]] = {}
    columns = max(layers.values()) + 1
    rows = max(sum(1 for v in layers.values() if v == c) for c in range(columns))
    fig, ax = plt.subplots(figsize=(max(8.0, 2.3 * columns), max(5.0, 0.9 * rows + 2.0)))
    # each column centred, in a stable order: processes, topics, then services at the bottom
    for c in range(columns):
        col = sorted((v for v in graph.nodes if layers[v] == c), key=lambda v: ("nts".index(v[0]), v[1]))
        for i, v in enumerate(col):
            pos[v] = (c, (len(col) - 1) / 2 - i)

    def edges(kind: str, direct: bool | None = None) -> list[tuple[Any, Any]]:
        out_edges = []
        for a, b, d in graph.edges(data=True):
            topic = a[1] if a[0] == "t" else b[1] if b[0] == "t" else None
            if d["kind"] == kind and (direct is None or (topic in g.direct) == direct):
                out_edges.append((a, b))
        return out_edges

    common = {"ax": ax, "arrows": True, "arrowstyle": "-|>", "arrowsize": 14, "node_size": 3200,
              "node_shape": "s", "connectionstyle": "arc3,rad=0.04"}
    for kind in ("pub", "sub"):
        nx.draw_networkx_edges(graph, pos, edgelist=edges(kind, False), edge_color="#555555", width=1.2, **common)
        nx.draw_networkx_edges(graph, pos, edgelist=edges(kind, True), edge_color="#e07000", width=2.6, **common)
    for a, b in edges("serve") + edges("call"):  # plain dashed lines: a link, not a data flow
        ax.plot([pos[a][0], pos[b][0]], [pos[a][1], pos[b][1]], ls="--", color="#a08000", lw=1.2, zorder=1)
    unheard = set(g.unheard())
    for v, d in graph.nodes(data=True):
        kind, name = d["kind"], v[1]
        if kind == _NODE:
            text = f"{_label(name)}\n{_label(g.nodes[name])}" if g.nodes[name] else _label(name)
            box = {"boxstyle": "round,pad=0.5", "fc": "#bcd6f5", "ec": "#1f4e8c", "lw": 1.5}
            weight = "bold"
        elif kind == _TOPIC:
            type_name = g.topics.get(name, "")
            text = _label(name) + (f"\n[{type_name}]" if type_name else "")
            dashed = name in unheard
            box = {"boxstyle": "round,pad=0.35", "fc": "white", "ec": "#e07000" if name in g.direct else "#777777",
                   "lw": 2.0 if name in g.direct else 1.0, "ls": "--" if dashed else "-"}
            weight = "normal"
        else:
            text = _label(name) + (f"\n[{g.services[name]}]" if g.services.get(name) else "")
            box = {"boxstyle": "round,pad=0.35", "fc": "#fff3b0", "ec": "#a08000", "lw": 1.0}
            weight = "normal"
        ax.text(*pos[v], text, ha="center", va="center", fontsize=10, fontweight=weight, bbox=box, zorder=3)
    handles = [Patch(fc="#bcd6f5", ec="#1f4e8c", label="node (process)"),
               Patch(fc="white", ec="#777777", label="topic via the bus [type]"),
               Line2D([], [], color="#e07000", lw=2.6, label="direct topic (past the proxy)"),
               Patch(fc="white", ec="#777777", ls="--", label="topic no node here publishes"),
               Patch(fc="#fff3b0", ec="#a08000", label="service (dashed: its server)"),
               Line2D([], [], color="#555555", lw=1.2, marker=">", label="publish -> topic -> subscribe")]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=3, fontsize=8, frameon=False)
    ax.set_title(g.title, fontsize=10)
    ax.set_xlim(-0.7, columns - 0.3)
    ax.margins(y=0.12)
    ax.axis("off")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    with matplotlib.rc_context({"svg.fonttype": "none"}):  # names stay text in an SVG: searchable, selectable
        fig.savefig(out, format=fmt, dpi=110)
    plt.close(fig)
    return out


def describe(g: GraphModel) -> Iterable[str]:
    """The same graph as text lines (printed after the picture is written)."""
    yield f"{len(g.nodes)} nodes, {len(g.topics)} topics ({len(g.direct & set(g.topics))} direct), " \
          f"{len(g.services)} services"
    for name in g.unheard():
        subs = sorted(n for n, t in g.subscribes if t == name)
        yield f"  {name}: subscribed by {', '.join(subs)}, published by no node in this graph"
