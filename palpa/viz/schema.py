"""JSON Schemas as the Foxglove app reads them, made from palpa's own (:func:`palpa.message.json_schema`).

msgspec writes a schema whose root is a ``$ref`` into ``$defs`` and whose fixed-length tuples use
``prefixItems`` (with ``items: false``). Foxglove wants an object at the root (its WebSocket protocol and the SDK refuse anything else)
and reads ``items`` to know what an array holds (the Plot panel's path completion), so the schema is inlined
and each tuple also gets an ``items`` when all its elements share one schema. Field names and meanings are
unchanged: a message validates against the result exactly when it validates against palpa's schema.
"""

from __future__ import annotations

import json
from typing import Any

from palpa.errors import RegistryError
from palpa.message import json_schema, lookup

__all__ = ["foxglove_schema", "inline_schema"]


def inline_schema(schema: dict[str, Any]) -> dict[str, Any]:
    """``schema`` with every local ``$ref`` replaced by its definition and ``$defs`` dropped.

    A recursive type keeps its ``$ref`` at the point of recursion (with ``$defs`` kept for it), so the result is
    always finite.
    """
    defs: dict[str, Any] = schema.get("$defs", {})
    recursive = False

    def walk(node: Any, stack: tuple[str, ...]) -> Any:
        nonlocal recursive
        if isinstance(node, list):
            return [walk(n, stack) for n in node]
        if not isinstance(node, dict):
            return node
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            name = ref[len("#/$defs/"):]
            if name in stack or name not in defs:
                recursive = True
                return node
            merged = {**defs[name], **{k: v for k, v in node.items() if k != "$ref"}}
            return walk(merged, (*stack, name))
        out = {k: walk(v, stack) for k, v in node.items() if k != "$defs"}
        items = out.get("prefixItems")
        if isinstance(items, list) and items and out.get("items") in (None, False) and all(i == items[0] for i in items):
            out["items"] = items[0]
        return out

    result: dict[str, Any] = walk(schema, ())
    if recursive:
        result["$defs"] = defs
    return result


def foxglove_schema(type_name: str) -> bytes | None:
    """The inlined JSON Schema of a registered message type as UTF-8 JSON, or None when the type is unknown."""
    try:
        cls = lookup(type_name)
    except RegistryError:
        return None
    schema = inline_schema(json_schema(cls))
    schema.setdefault("type", "object")
    return json.dumps(schema, sort_keys=True).encode()
