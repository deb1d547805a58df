"""Validation of marked YAML against msgspec Structs, with msgspec's errors turned into ``file:line:col: ...``
messages (an unknown key with the closest allowed one, a missing key, a wrong type or bound at its value)."""

from __future__ import annotations

import difflib
import re
import sys
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from yamlstruct.source import Path_, Source

__all__ = ["convert", "did_you_mean", "kind", "label", "load", "lower_first"]

T = TypeVar("T")

_ERR_PATH_RE = re.compile(r"^(?P<what>.*) - at `\$(?P<path>[^`]*)`$", re.S)
_PATH_PART_RE = re.compile(r"\.([A-Za-z_][\w-]*)|\[(\d+)\]|\[\.\.\.\]")


def load(path: Path, typ: type[T], source: type[Source] = Source) -> tuple[T, Source]:
    """Read the YAML file ``path`` and convert it to ``typ``; errors (``source.error_type``) name file:line:col."""
    src = source.read(path)
    return convert(src, src.data, typ), src


def convert(src: Source, data: Any, typ: Any, base: Path_ = (), root: Any = None) -> Any:
    """``data`` (from ``src`` at ``base``) as ``typ``, strictly; ``src.error_type`` at the offending key otherwise.
    ``root`` is the type of the whole file (for the allowed keys of a mapping; default ``typ``, at ``base``)."""
    try:
        return msgspec.convert(data, typ, strict=True)
    except msgspec.ValidationError as exc:
        raise _validation_error(src, base, str(exc), typ if root is None else root,
                                base if root is None else ()) from None


def _validation_error(src: Source, base: Path_, text: str, root: Any, root_path: Path_) -> Exception:
    m = _ERR_PATH_RE.match(text)
    what, rel = (m.group("what"), m.group("path")) if m else (text, "")
    path: Path_ = base
    for part in _PATH_PART_RE.finditer(rel):
        if part.group(1) is not None:
            path = (*path, part.group(1))
        elif part.group(2) is not None:
            path = (*path, int(part.group(2)))
        else:  # a value inside a dict: msgspec does not say which key, so find the first of the wrong kind
            wrong = re.search(r"got `(\w+)`", what)
            container = src.get(path)
            if isinstance(container, dict) and wrong:
                for k, v in container.items():
                    if _kind_name(v) == wrong.group(1):
                        path = (*path, k)
                        break
    named = label(path, src.document)
    unknown = re.match(r"Object contains unknown field `([^`]+)`", what)
    if unknown:
        key = unknown.group(1)
        allowed = _allowed_keys(root, path[len(root_path):])
        return src.error((*path, key), f"unknown key {key!r} in {named}{did_you_mean(key, allowed)}; expected "
                                       f"one of: {', '.join(allowed)}", key=True)
    missing = re.match(r"Object missing required field `([^`]+)`", what)
    if missing:
        return src.error(path, f"{named} is missing the required key {missing.group(1)!r}")
    for bound in (f" <= {sys.float_info.max!r}", f" >= {-sys.float_info.max!r}"):  # the bound that means finite
        what = what.replace(f"`float`{bound}", "a finite `float`")
    value = src.get(path)
    shown = f", got {value!r}" if " got " not in what and value is not None else ""  # a bound: show the value
    return src.error(path, f"{named}: {lower_first(what)}{shown}")


def _allowed_keys(root: Any, path: Path_) -> list[str]:
    typ: Any = _struct_in(root)
    for part in path:
        if isinstance(part, int):
            continue
        hints = {f.name: f.type for f in msgspec.structs.fields(typ)} if isinstance(typ, type) else {}
        sub = hints.get(str(part))
        typ = _struct_in(sub)
        if typ is None:
            return []
    return [f.name for f in msgspec.structs.fields(typ)] if isinstance(typ, type) else []


def _struct_in(t: Any) -> Any:
    """The Struct type inside an annotation like ``list[X]``, ``X | None`` or ``Annotated[...]``."""
    if isinstance(t, type) and issubclass(t, msgspec.Struct):
        return t
    for arg in getattr(t, "__args__", ()):
        found = _struct_in(arg)
        if found is not None:
            return found
    origin = getattr(t, "__origin__", None)
    return _struct_in(origin) if origin is not None and origin is not t else None


def label(path: Path_, document: str) -> str:
    """How the value at ``path`` is named in messages (``nodes[2].params.rate_hz``); ``document`` for the root."""
    if not path:
        return document
    text = str(path[0])
    for part in path[1:]:
        text += f"[{part}]" if isinstance(part, int) else f".{part}"
    return text


def kind(value: Any) -> str:
    """What a YAML value is, in words (mapping, list, string, ...)."""
    return {"object": "mapping", "array": "list", "str": "string", "null": "null"}.get(_kind_name(value),
                                                                                      _kind_name(value))


def _kind_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, dict):
        return "object"
    if isinstance(value, list):
        return "array"
    return type(value).__name__


def lower_first(text: str) -> str:
    """msgspec's messages start with a capital; ours continue a sentence."""
    return text[:1].lower() + text[1:]


def did_you_mean(name: str, choices: Any) -> str:
    """The hint `` (did you mean 'x'?)`` naming the closest of ``choices``, or an empty string."""
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""
