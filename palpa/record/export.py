"""``palpa bag export FILE --json OUT``: a JSON-encoded MCAP (schema encoding ``jsonschema``) for viewers.

Foxglove and friends decode ``json`` + ``jsonschema`` channels natively, so every field is readable there. Each
msgpack payload is decoded without the message code and re-encoded as JSON (binary fields become base64 strings,
as the msgspec JSON Schemas say; NaN/inf become null). Schemas are the recorded ones with ``$ref``s inlined
(viewers handle plain nested objects best). Blob frames are dropped with a note by default, or exported as base64
on ``_palpa/blobs/<topic>`` channels. The output is written with the official ``mcap`` Writer.

A payload that is not msgpack, nests deeper than ``palpa.net.wire.MAX_NESTING`` or has no JSON form is exported as a
placeholder ``{"_palpa_error", "_palpa_index", "_palpa_msgpack_base64"}`` and listed in the report; everything
else is exported all the same, and ``palpa bag export`` then ends with status 1.
"""

from __future__ import annotations

import base64
import copy
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
from mcap.records import Attachment, McapRecord, Metadata, Schema
from mcap.writer import CompressionType, Writer

import palpa
from palpa.atomic import written_beside
from palpa.errors import DecodeError
from palpa.net.wire import decode_any
from palpa.record.format import (
    BLOBS_TOPIC_PREFIX,
    META_LATCHED,
    META_PUBLISHER,
    META_TYPE,
    SCHEMA_ENCODING,
    BagError,
    schema_bytes,
)
from palpa.record.reader import iter_bag

__all__ = ["ExportReport", "export_json", "inline_refs"]

_BLOBS_JSON_SCHEMA = json.dumps({
    "title": "palpa.Blobs", "type": "object",
    "properties": {"blobs": {"type": "array", "items": {"type": "string", "contentEncoding": "base64"}}},
}).encode()


_PLACEHOLDERS_LISTED = 10


@dataclass
class ExportReport:
    """What :func:`export_json` wrote. ``placeholders``: (index in the recording, topic, why) of every message
    exported as a placeholder instead of its fields."""

    output: Path
    messages: int = 0
    blobs_dropped: int = 0
    placeholders: list[tuple[int, str, str]] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """Whether every message was exported field by field (what viewers show)."""
        return not self.placeholders

    def text(self) -> str:
        notes = []
        if self.blobs_dropped:
            notes.append(f"{self.blobs_dropped} blob frames dropped (use --blobs base64 to keep them)")
        if self.placeholders:
            listed = ", ".join(f"#{i} on {topic!r} ({why})" for i, topic, why in
                               self.placeholders[:_PLACEHOLDERS_LISTED])
            more = len(self.placeholders) - _PLACEHOLDERS_LISTED
            notes.append(f"{len(self.placeholders)} message(s) exported as placeholders (their msgpack as base64 "
                         f"under _palpa_msgpack_base64): {listed}" + (f" and {more} more" if more > 0 else ""))
        return f"exported {self.messages} messages to {self.output}" + (f"; {'; '.join(notes)}" if notes else "")


def inline_refs(schema: dict[str, Any]) -> dict[str, Any]:
    """Replace ``{"$ref": "#/$defs/X"}`` by the definition itself, recursively; recursive types keep their refs."""
    defs = schema.get("$defs", {})
    kept: set[str] = set()

    def walk(node: Any, stack: tuple[str, ...]) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                name = ref[len("#/$defs/"):]
                if name in stack or name not in defs:
                    kept.add(name)
                    return node
                merged = {**copy.deepcopy(defs[name]), **{k: v for k, v in node.items() if k != "$ref"}}
                return walk(merged, (*stack, name))
            return {k: walk(v, stack) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [walk(v, stack) for v in node]
        return node

    out: dict[str, Any] = walk(schema, ())
    if kept:
        out["$defs"] = {k: defs[k] for k in kept if k in defs}
    return out


def _to_json(payload: bytes) -> tuple[bytes | None, str]:
    """The payload as JSON, or (None, why not)."""
    try:
        return msgspec.json.encode(decode_any(payload)), ""
    except DecodeError as exc:
        return None, str(exc)
    except (msgspec.EncodeError, TypeError, ValueError) as exc:
        return None, f"not representable as JSON: {exc}"


def export_json(paths: Sequence[Path], out: str | os.PathLike[str], *, blobs: str = "drop",
                overwrite: bool = False) -> ExportReport:
    """Write every message of the recording ``paths`` (one file or a split set) as JSON into one MCAP ``out``."""
    if blobs not in ("drop", "base64"):
        raise BagError(f"--blobs {blobs!r}: expected drop or base64")
    output = Path(out)
    if output.exists() and not overwrite:
        raise BagError(f"{output} already exists (use --force to overwrite)")
    report = ExportReport(output)
    recorded_schemas: dict[str, bytes] = {}
    metadata: list[Metadata] = []
    attachments: dict[tuple[str, bytes], Attachment] = {}

    def on_record(rec: McapRecord) -> None:
        if isinstance(rec, Schema) and rec.encoding == SCHEMA_ENCODING and rec.data:
            recorded_schemas.setdefault(rec.name, rec.data)
        elif isinstance(rec, Metadata):
            metadata.append(rec)
        elif isinstance(rec, Attachment):
            attachments.setdefault((rec.name, rec.data), rec)

    with written_beside(output) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(library=f"palpa/{palpa.__version__} bag export")
        schema_ids: dict[str, int] = {}
        channel_ids: dict[tuple[str, str, str, bool], int] = {}

        def schema_for(type_name: str) -> int:
            if type_name not in schema_ids:
                raw = recorded_schemas.get(type_name) or schema_bytes(type_name)
                schema_ids[type_name] = w.register_schema(
                    type_name, SCHEMA_ENCODING, json.dumps(inline_refs(json.loads(raw))).encode()
                ) if raw else 0
            return schema_ids[type_name]

        def channel_for(topic: str, type_name: str, node: str, latched: bool) -> int:
            key = (topic, type_name, node, latched)
            if key not in channel_ids:
                sid = (w.register_schema("palpa.Blobs", SCHEMA_ENCODING, _BLOBS_JSON_SCHEMA)
                       if type_name == "palpa.Blobs" else schema_for(type_name))
                channel_ids[key] = w.register_channel(topic, "json", sid, {
                    META_TYPE: type_name, META_PUBLISHER: node, META_LATCHED: "true" if latched else "false"})
            return channel_ids[key]

        for index, m in enumerate(iter_bag(paths, on_record=on_record)):
            data, why = _to_json(m.payload)
            if data is None:
                report.placeholders.append((index, m.topic, why))
                data = msgspec.json.encode({"_palpa_error": why, "_palpa_index": index,
                                            "_palpa_msgpack_base64": base64.b64encode(m.payload).decode()})
            cid = channel_for(m.topic, m.type, m.node, m.latched)
            w.add_message(cid, log_time=m.log_time, data=data, publish_time=m.publish_time,
                          sequence=m.seq & 0xFFFF_FFFF)
            report.messages += 1
            if m.blobs:
                if blobs == "drop":
                    report.blobs_dropped += len(m.blobs)
                else:
                    bid = channel_for(BLOBS_TOPIC_PREFIX + m.topic, "palpa.Blobs", m.node, False)
                    w.add_message(bid, log_time=m.log_time, publish_time=m.publish_time,
                                  sequence=m.seq & 0xFFFF_FFFF, data=msgspec.json.encode(
                                      {"blobs": [base64.b64encode(b).decode() for b in m.blobs]}))
        for md in metadata:
            w.add_metadata(md.name, md.metadata)
        w.add_metadata("palpa.export", {"source": ", ".join(map(str, paths)), "note": report.text()})
        for att in attachments.values():
            w.add_attachment(att.create_time, att.log_time, att.name, att.media_type, att.data)
        w.finish()  # type: ignore[no-untyped-call]
    return report
