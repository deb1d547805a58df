"""The conventions of a palpa recording, shared by the writer, recorder, player and the offline tools.

An MCAP file written by palpa holds:

* one **channel** per (topic, publisher node, type, latched, sequence epoch), message encoding ``msgpack``, with
  channel metadata ``palpa.type``, ``palpa.publisher``, ``palpa.latched`` (``"true"``/``"false"``) and, only
  when the publisher's sequence number passed 2**32, ``palpa.seq_base`` (MCAP's ``sequence`` is a uint32; the
  envelope's sequence is ``seq_base + sequence``);
* one **schema** per message type, encoding ``jsonschema``, name = the palpa type name, data = the JSON Schema
  from :func:`palpa.message.json_schema`. A type the recorder could not import gets no schema (schema id 0, which
  the MCAP registry allows for self-describing encodings such as msgpack) and the channel metadata
  ``palpa.schema`` says why;
* **messages** whose data are the wire payload bytes exactly as received; ``log_time`` is when the recorder
  received it, ``publish_time`` the envelope stamp, ``sequence`` the envelope sequence number;
* blobs (envelope frames 3+) of a message, when it has any, as one message on a companion channel
  ``_palpa/blobs/<topic>`` (metadata ``palpa.blobs_of`` = the main channel id) written right BEFORE it with the
  same log time and sequence (so a reader never has to look ahead); its data is a msgpack array of the raw
  blob frames;
* **metadata** records ``palpa.recording`` (palpa version, host, recorder parameters, split index),
  ``palpa.nodes`` (node name -> JSON of its last heartbeat: pid, host, publishes, subscribes; rewritten when the
  graph changes, the last one wins), ``palpa.drops`` (topic -> JSON counters; written when a file is closed, or by
  ``palpa bag recover``) and ``palpa.recovery`` (only in recovered files);
* the resolved launch file as the attachment ``launch.resolved.yaml`` when the run came from one.
"""

from __future__ import annotations

import contextlib
import glob
import importlib
import json
import os
import re
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

from palpa import env as palpa_env
from palpa.errors import PalpaError, RegistryError
from palpa.message import json_schema, lookup
from palpa.targets import import_message_modules

__all__ = [
    "BLOBS_TOPIC_PREFIX",
    "BagError",
    "LAUNCH_ATTACHMENT",
    "MAGIC",
    "MD_DROPS",
    "MD_NODES",
    "MD_RECORDING",
    "MD_RECOVERY",
    "MESSAGE_ENCODING",
    "META_BLOBS_OF",
    "META_LATCHED",
    "META_PUBLISHER",
    "META_SCHEMA",
    "META_SEQ_BASE",
    "META_TYPE",
    "RUNTIME_PREFIX",
    "SCHEMA_ENCODING",
    "TopicFilter",
    "import_message_modules",
    "schema_bytes",
    "split_path",
    "split_pieces",
]

MAGIC = b"\x89MCAP0\r\n"
MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"

META_TYPE = "palpa.type"
META_PUBLISHER = "palpa.publisher"
META_LATCHED = "palpa.latched"
META_SEQ_BASE = "palpa.seq_base"
META_SCHEMA = "palpa.schema"
META_BLOBS_OF = "palpa.blobs_of"

MD_RECORDING = "palpa.recording"
MD_NODES = "palpa.nodes"
MD_DROPS = "palpa.drops"
MD_RECOVERY = "palpa.recovery"

LAUNCH_ATTACHMENT = "launch.resolved.yaml"
BLOBS_TOPIC_PREFIX = "_palpa/blobs/"
BLOBS_SCHEMA_NAME = "palpa.Blobs"
BLOBS_SCHEMA = json.dumps(
    {"title": BLOBS_SCHEMA_NAME, "type": "array", "items": {"type": "string", "contentEncoding": "base64"}}
).encode()
RUNTIME_PREFIX = "_palpa/"


class BagError(PalpaError):
    """A recording cannot be written, read, recovered or played; the message names the file and the problem."""


NODE_MODULES_ENV = palpa_env.NODE_MODULES
"""Set by ``palpa launch`` on its recorder: the modules of the launched node classes, comma-separated."""
_nodes_imported = False


def _import_node_modules() -> None:
    """Import the launched nodes' modules (once): a custom node's message types are registered by importing
    the module that defines (or imports) them, so a launch records them with no setting."""
    global _nodes_imported
    if _nodes_imported:
        return
    _nodes_imported = True
    for name in filter(None, os.environ.get(NODE_MODULES_ENV, "").split(",")):
        with contextlib.suppress(Exception):  # a node module that fails to import costs only its schemas
            importlib.import_module(name.strip())


def schema_bytes(type_name: str) -> bytes | None:
    """The JSON Schema of a registered message type as UTF-8 JSON, or None when the type is not importable.
    A type not in ``messages`` or ``PALPA_MESSAGES`` is looked for in the launched nodes' modules."""
    import_message_modules()
    try:
        cls = lookup(type_name)
    except RegistryError:
        _import_node_modules()
        try:
            cls = lookup(type_name)
        except RegistryError:
            return None
    return json.dumps(json_schema(cls), sort_keys=True).encode()


def _split_parts(base: str | os.PathLike[str]) -> tuple[Path, str, str]:
    p = Path(base)
    return p.parent, (p.stem if p.suffix else p.name), (p.suffix or ".mcap")


def split_path(base: str | os.PathLike[str], index: int) -> Path:
    """The path of piece ``index`` (1-based) of a split recording: ``run.mcap`` -> ``run-0001.mcap``."""
    parent, stem, suffix = _split_parts(base)
    return parent / f"{stem}-{index:04d}{suffix}"


def split_pieces(base: str | os.PathLike[str]) -> list[Path]:
    """Existing pieces of a split recording named ``base``, in order."""
    parent, stem, suffix = _split_parts(base)
    return sorted(parent.glob(f"{glob.escape(stem)}-[0-9][0-9][0-9][0-9]{suffix}"))


def _compile(patterns: Sequence[str], what: str) -> list[re.Pattern[str]]:
    out = []
    for pat in patterns:
        try:
            out.append(re.compile(pat))
        except re.error as exc:
            raise BagError(f"{what} regex {pat!r} is invalid: {exc}") from None
    return out


class TopicFilter:
    """Which topics to take: ``include``/``exclude`` are regular expressions matched against the WHOLE topic name.

    Empty ``include`` means every topic. Runtime topics (``_palpa/...``) are taken only when an include pattern
    that itself starts with ``_palpa`` matches them, or when they are listed in ``always`` (the recorder keeps
    ``_palpa/log``: a run's log lines belong to its record). ``exclude`` wins over everything.
    """

    def __init__(self, include: Sequence[str] = (), exclude: Sequence[str] = (), *,
                 always: Collection[str] = ()) -> None:
        self.include = _compile(include, "topic")
        self.exclude = _compile(exclude, "exclude")
        self.always = frozenset(always)
        self._runtime_include = [p for p in self.include if p.pattern.lstrip("^").startswith("_palpa")]
        self._cache: dict[str, bool] = {}

    def __call__(self, topic: str) -> bool:
        hit = self._cache.get(topic)
        if hit is None:
            hit = self._cache[topic] = self._decide(topic)
        return hit

    def _decide(self, topic: str) -> bool:
        if any(p.fullmatch(topic) for p in self.exclude):
            return False
        if topic.startswith(RUNTIME_PREFIX):
            return topic in self.always or any(p.fullmatch(topic) for p in self._runtime_include)
        return not self.include or any(p.fullmatch(topic) for p in self.include)


def dumps(obj: Any) -> str:
    """Compact, key-sorted JSON for metadata values."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))
