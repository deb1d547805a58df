"""Names on the bus: what a topic written in a node is called on the bus (remapping, namespaces), and the name a
node gets when it is given none.

Separate from :mod:`palpa.node.node` because these are pure string rules that do not need a node: the launcher resolves
the topics a node class declares without starting it (:mod:`palpa.launch.topics`).
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["RUNTIME_PREFIX", "default_node_name", "resolve_topic"]

RUNTIME_PREFIX = "_palpa/"
"""Topics of the runtime itself (clock, heartbeats, logs, parameters, services): never namespaced, and not counted
in what a node tells a lockstep clock."""


def resolve_topic(topic: str, namespace: str, remap: Mapping[str, str]) -> str:
    """A topic as written in a node -> its name on the bus: remapped, then prefixed by the namespace unless absolute
    (``/x``) or a runtime topic (``_palpa/...``); a remap of the namespaced name applies last."""
    topic = remap.get(topic, topic)
    if topic.startswith("/"):
        return topic[1:]
    namespace = namespace.strip("/")
    if topic.startswith(RUNTIME_PREFIX) or not namespace:
        return topic
    resolved = f"{namespace}/{topic}"
    return remap.get(resolved, resolved)


def default_node_name(class_name: str) -> str:
    """A node class's name in snake case (``ForceSensor`` -> ``force_sensor``): a node's name when given none."""
    out = []
    for i, ch in enumerate(class_name):
        if ch.isupper() and i and not class_name[i - 1].isupper():
            out.append("_")
        out.append(ch.lower())
    return "".join(out)
