"""A recording as tables: one pandas DataFrame per topic, fields flattened, read without the message code.

Each row is one recorded message. The first four columns describe the envelope (``_log_time_ns``: when the recorder
received it, ``_publish_time_ns``: the publisher's stamp, ``_sequence``: the envelope's sequence number,
``_publisher``: the publishing node; a topic that carried several types also gets ``_type``); the leading
underscore keeps them apart from any message field. Message fields follow in the payload's order:

* a nested message (a msgpack map) becomes dotted columns, ``pose.position.x``;
* a fixed-length array (the schema's ``prefixItems``, a ``tuple[float, float, float, float]``) becomes one column
  per element, ``h_mm.0`` .. ``h_mm.3``; a variable-length list stays one cell holding the list;
* a field whose JSON Schema states a unit (``"x-unit": "N"``, from ``msgspec.Meta(extra_json_schema=...)``) and
  whose name does not already end in it is named ``force[N]``. palpa's own messages carry their units in their
  field names (``force_n``, ``x_mm``: messages/__init__.py), which the columns keep.

The schemas come from the recording itself, so any recording reads back without the code that wrote it; a channel
without a schema is flattened the same way except that arrays stay lists.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.records import McapRecord, Schema

from palpa.errors import DecodeError
from palpa.net.wire import decode_any
from palpa.record.export import inline_refs
from palpa.record.format import SCHEMA_ENCODING, BagError, TopicFilter
from palpa.record.reader import BagMessage, iter_bag, resolve_bag_paths

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["ENVELOPE_COLUMNS", "Flattener", "read", "read_rows"]

ENVELOPE_COLUMNS = ("_log_time_ns", "_publish_time_ns", "_sequence", "_publisher")
_MAX_DEPTH = 32  # deeper nesting is kept as one cell: a column name per level would be unreadable anyway


@dataclass
class _Shape:
    """What the schema says about one field: its unit, its fixed length (an array), its fields (a nested map)."""

    unit: str = ""
    length: int = 0
    items: list[_Shape] = field(default_factory=list)
    fields: dict[str, _Shape] = field(default_factory=dict)


def _shape(node: Any, depth: int = 0) -> _Shape:
    if not isinstance(node, dict) or depth > _MAX_DEPTH:
        return _Shape()
    unit = node.get("x-unit")
    shape = _Shape(unit=unit if isinstance(unit, str) else "")
    prefix = node.get("prefixItems")
    if isinstance(prefix, list) and node.get("items") is False:
        shape.length = len(prefix)
        shape.items = [_shape(p, depth + 1) for p in prefix]
    props = node.get("properties")
    if isinstance(props, dict):
        shape.fields = {str(k): _shape(v, depth + 1) for k, v in props.items()}
    return shape


def _named(name: str, shape: _Shape) -> str:
    unit = shape.unit
    if not unit or name.lower().endswith("_" + unit.lower()):
        return name
    return f"{name}[{unit}]"


class Flattener:
    """Turns decoded payloads of one message type into flat rows, guided by the type's JSON Schema (or none)."""

    def __init__(self, schema: bytes | None) -> None:
        root: Any = None
        if schema:
            try:
                root = inline_refs(json.loads(schema))
            except (ValueError, RecursionError):
                root = None
        self._root = _shape(root)

    def flatten(self, value: Any) -> dict[str, Any]:
        """``value`` (a decoded payload) as ``{column: cell}``; a payload that is not a map is one ``value`` cell."""
        out: dict[str, Any] = {}
        if isinstance(value, dict):
            self._walk(value, self._root, "", out, 0)
        else:
            out["value"] = value
        return out

    def _walk(self, value: dict[Any, Any], shape: _Shape, prefix: str, out: dict[str, Any], depth: int) -> None:
        for key, cell in value.items():
            sub = shape.fields.get(str(key), _Shape())
            name = prefix + _named(str(key), sub)
            self._cell(cell, sub, name, out, depth)

    def _cell(self, cell: Any, shape: _Shape, name: str, out: dict[str, Any], depth: int) -> None:
        if depth < _MAX_DEPTH and isinstance(cell, dict) and cell:
            self._walk(cell, shape, name + ".", out, depth + 1)
        elif depth < _MAX_DEPTH and isinstance(cell, list) and shape.length and len(cell) == shape.length:
            for i, item in enumerate(cell):
                self._cell(item, shape.items[i], f"{name}.{i}", out, depth + 1)
        else:
            out[name] = cell


@dataclass
class TopicRows:
    """The rows of one topic, in recorded order, with the message types seen on it."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    types: list[str] = field(default_factory=list)


def read_rows(paths: Sequence[Path], topics: TopicFilter) -> Iterator[tuple[str, dict[str, Any]]]:
    """(topic, flat row) for every message of the selected topics, in file order. A payload that is not msgpack
    raises :class:`BagError` naming the topic and sequence number (a table with a hole would look complete)."""
    schemas: dict[str, bytes] = {}
    flatteners: dict[str, Flattener] = {}

    def on_record(rec: McapRecord) -> None:
        if isinstance(rec, Schema) and rec.encoding == SCHEMA_ENCODING and rec.data:
            schemas.setdefault(rec.name, bytes(rec.data))

    m: BagMessage
    for m in iter_bag(paths, on_record=on_record):
        if not topics(m.topic):
            continue
        try:
            value = decode_any(m.payload)  # nesting-bounded, as every decode of what the wire carried
        except (DecodeError, ValueError) as exc:
            raise BagError(f"{m.topic}: the message with sequence number {m.seq} is not msgpack ({exc}); "
                           "nothing was exported") from None
        flat = flatteners.get(m.type)
        if flat is None:
            flat = flatteners[m.type] = Flattener(schemas.get(m.type))
        row: dict[str, Any] = {"_log_time_ns": m.log_time, "_publish_time_ns": m.publish_time, "_sequence": m.seq,
                               "_publisher": m.node, "_type": m.type}
        row.update(flat.flatten(value))
        yield m.topic, row


def read(path: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], topics: Sequence[str] | str | None = None,
         *, exclude: Sequence[str] = ()) -> dict[str, pd.DataFrame]:
    """The recording at ``path`` (a .mcap file, a split set's base name, a run directory, or a list of them) as
    ``{topic: DataFrame}``, one row per message, columns as the module docstring says.

    ``topics`` are regular expressions matched against the whole topic name (a plain name matches itself);
    none means every topic (runtime ``_palpa/...`` topics only when a pattern names them, as ``palpa play``).
    Raises :class:`BagError` for a file that cannot be read or a payload that is not msgpack."""
    import pandas as pd

    wanted = [topics] if isinstance(topics, str) else list(topics or ())
    out: dict[str, TopicRows] = {}
    for topic, row in read_rows(resolve_bag_paths(path), TopicFilter(wanted, exclude)):
        t = out.setdefault(topic, TopicRows())
        if row["_type"] not in t.types:
            t.types.append(row["_type"])
        t.rows.append(row)
    frames: dict[str, pd.DataFrame] = {}
    for topic in sorted(out):
        t = out[topic]
        df = pd.DataFrame.from_records(t.rows)
        if len(t.types) == 1:
            df = df.drop(columns="_type")
        frames[topic] = df
    return frames
