"""The topics a node class declares, read from its source without running it (``palpa launch --check``).

Starting a node to ask it would open its hardware, so ``--check`` reads the class's code instead: every
``self.publisher("topic", ...)``, ``self.subscribe("topic", ...)`` and ``self.subscribe_raw("prefix", ...)`` with a
literal name (or a module-level string constant), in the class and its palpa base classes. Names built at run
time are reported as ``(computed)``.
Topics declared only for some parameter values (a sim driver's inputs) are listed all the same.
"""

from __future__ import annotations

import ast
import inspect
import textwrap
from collections.abc import Mapping

from palpa.node.naming import resolve_topic
from palpa.node.node import Node

__all__ = ["declared_topics"]

_PUB = {"publisher"}
_SUB = {"subscribe", "subscribe_raw"}


def _runtime_topic_of(fn: object, n_args: int) -> str | None:
    """What ``fn`` names with placeholder arguments, if that is a runtime topic (``_palpa/...``), else None: a topic
    computed from a node's name or a parameter cannot be listed, but one the runtime computes is not the user's."""
    if not callable(fn) or not getattr(fn, "__module__", "").startswith("palpa."):
        return None  # only the runtime's own pure name functions are called; a user's may do anything
    try:
        name = fn(*(["{arg}"] * n_args))
    except Exception:  # noqa: BLE001  (any failure: just not a known runtime topic)
        return None
    return name if isinstance(name, str) and name.startswith("_palpa/") else None


def declared_topics(cls: type[Node], namespace: str = "",
                    remap: Mapping[str, str] | None = None) -> dict[str, list[str]]:
    """``{"publishes": [...], "subscribes": [...]}`` as the node will name them on the bus (remapped and
    namespaced); runtime topics (``_palpa/...``) are left out."""
    pubs: set[str] = set()
    subs: set[str] = set()
    for klass in cls.__mro__:
        if klass is Node or not issubclass(klass, Node):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        for call in ast.walk(tree):
            if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                    and isinstance(call.func.value, ast.Name) and call.func.value.id == "self"):
                continue
            kind = pubs if call.func.attr in _PUB else subs if call.func.attr in _SUB else None
            if kind is None or not call.args:
                continue
            arg = call.args[0]
            literal = arg.value if isinstance(arg, ast.Constant) else None
            if isinstance(arg, ast.Name):  # a module-level constant such as CLOCK_TOPIC
                literal = vars(inspect.getmodule(klass)).get(arg.id)
            elif isinstance(arg, ast.Call) and isinstance(arg.func, ast.Name) and not arg.keywords:
                # a module-level topic function such as tick_topic(node): a runtime topic whatever its arguments?
                literal = _runtime_topic_of(vars(inspect.getmodule(klass)).get(arg.func.id), len(arg.args))
            if isinstance(literal, str):
                name = resolve_topic(literal, namespace, remap or {})
                if call.func.attr == "subscribe_raw":
                    name += "*"
                if not name.startswith("_palpa/"):
                    kind.add(name)
            else:
                kind.add("(computed)")
    return {"publishes": sorted(pubs), "subscribes": sorted(subs)}
