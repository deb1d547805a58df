"""Reading a YAML file while keeping where every key and value came from (``file:line:col``).

PyYAML composes the document into nodes that carry their marks; we build plain Python values from them ourselves,
with YAML 1.2 core-schema scalars (``true``/``false`` only — ``yes``/``no``/``on``/``off`` stay strings; no
timestamps; quoted scalars are always strings), string keys only, duplicate keys as errors, and ``<<`` merge keys.
Each value's position is recorded under its path (``("nodes", 0, "params", "rate_hz")``), so a validation error
found later can name the exact line and column.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Self

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

__all__ = ["Mark", "Path_", "Source", "YamlError", "display_path", "parse_scalar"]


class YamlError(ValueError):
    """A YAML file that cannot be read or does not hold what it should; the message starts ``file:line:col:``."""

Path_ = tuple[str | int, ...]

_PLAIN = "!palpa/plain"
_MERGE = "tag:yaml.org,2002:merge"
_STR = "tag:yaml.org,2002:str"
_SEQ = "tag:yaml.org,2002:seq"
_MAP = "tag:yaml.org,2002:map"
_INT_RE = re.compile(r"^[-+]?[0-9]+$")
_FLOAT_RE = re.compile(r"^[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?$")
_NULLS = {"", "~", "null", "Null", "NULL"}
_BOOLS = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}


@dataclass(frozen=True)
class Mark:
    """A position in a file; ``line`` and ``col`` are 1-based, as editors show them."""

    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"


def display_path(path: Path) -> str:
    """How a file is named in messages: relative to the working directory when below it, else absolute."""
    try:
        rel = os.path.relpath(path)
    except ValueError:
        return str(path)
    return str(path) if rel.startswith("..") else rel


class _Loader(yaml.SafeLoader):
    """Tags every plain scalar as ``!palpa/plain`` so we apply our own (YAML 1.2 core) scalar rules."""

    def resolve(self, kind: type[Node], value: Any, implicit: tuple[bool, bool]) -> str:
        if kind is ScalarNode and implicit[0]:
            return _MERGE if value == "<<" else _PLAIN
        return str(super().resolve(kind, value, implicit))  # type: ignore[no-untyped-call]


def parse_scalar(text: str) -> Any:
    """A plain YAML scalar under the YAML 1.2 core schema: null, bool, int, float, else the string itself.
    Also used for ``name:=value`` overrides on the command line."""
    if text in _NULLS:
        return None
    if text in _BOOLS:
        return _BOOLS[text]
    if _INT_RE.match(text):
        return int(text, 10)
    if re.match(r"^0x[0-9a-fA-F]+$", text):
        return int(text, 16)
    if re.match(r"^0o[0-7]+$", text):
        return int(text[2:], 8)
    if _FLOAT_RE.match(text):
        return float(text)
    low = text.lower()
    if low in (".inf", "+.inf"):
        return math.inf
    if low == "-.inf":
        return -math.inf
    if low == ".nan":
        return math.nan
    return text


@dataclass
class Source:
    """One YAML file: its data as plain Python values and the marks of every key and value.

    Errors are :attr:`error_type` (a subclass sets its own, e.g. the launcher's LaunchError); :attr:`document`
    names the whole file in messages."""

    error_type: ClassVar[type[Exception]] = YamlError
    document: ClassVar[str] = "the file"

    path: Path
    name: str
    data: Any
    value_marks: dict[Path_, Mark] = field(default_factory=dict)
    key_marks: dict[Path_, Mark] = field(default_factory=dict)

    @classmethod
    def read(cls, path: Path) -> Self:
        """Parse ``path``; raises :attr:`error_type` with ``file:line:col`` on malformed YAML."""
        name = display_path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise cls.error_type(f"{name}:1:1: not a UTF-8 text file ({exc.reason})") from None
        except OSError as exc:
            raise cls.error_type(f"{name}: cannot read: {exc.strerror}") from None
        return cls.from_text(text, name, path)

    @classmethod
    def from_text(cls, text: str, name: str, path: Path | None = None) -> Self:
        """Parse YAML ``text`` named ``name`` in messages (``path`` is the file it came from, if any)."""
        path = path if path is not None else Path(name)
        try:
            root = yaml.compose(text, Loader=_Loader)  # noqa: S506 - _Loader derives from SafeLoader
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            where = f"{name}:{mark.line + 1}:{mark.column + 1}" if mark else f"{name}:1:1"
            what = exc.problem or exc.context or "malformed YAML"
            raise cls.error_type(f"{where}: invalid YAML: {what}") from None
        except yaml.YAMLError as exc:
            raise cls.error_type(f"{name}:1:1: invalid YAML: {exc}") from None
        src = cls(path=path, name=name, data=None)
        src.data = None if root is None else src._build(root, ())
        return src

    # -- marks and errors ----------------------------------------------------------------------------
    def mark(self, path: Path_, *, key: bool = False) -> Mark:
        """The mark of the value at ``path`` (or of its key), falling back to the nearest enclosing value."""
        if key and path in self.key_marks:
            return self.key_marks[path]
        p = path
        while p:
            if p in self.value_marks:
                return self.value_marks[p]
            p = p[:-1]
        return self.value_marks.get((), Mark(self.name, 1, 1))

    def error(self, path: Path_, message: str, *, key: bool = False) -> Exception:
        """An :attr:`error_type` reading ``file:line:col: message`` for the value (or key) at ``path`` (only
        ``name: message`` for data that came from no text, such as a mapping a program built)."""
        where = self.mark(path, key=key) if self.value_marks else self.name
        return self.error_type(f"{where}: {message}")

    def get(self, path: Path_) -> Any:
        """The raw value at ``path`` (None if absent)."""
        value = self.data
        for part in path:
            try:
                value = value[part]
            except (KeyError, IndexError, TypeError):
                return None
        return value

    # -- building --------------------------------------------------------------------------------------
    def _mk(self, node: Node) -> Mark:
        return Mark(self.name, node.start_mark.line + 1, node.start_mark.column + 1)

    def _build(self, node: Node, path: Path_) -> Any:
        self.value_marks[path] = self._mk(node)
        if isinstance(node, ScalarNode):
            return self._scalar(node)
        if node.tag not in (_SEQ, _MAP):
            raise self.error_type(f"{self._mk(node)}: unsupported YAML tag {node.tag!r} (plain data only)")
        if isinstance(node, SequenceNode):
            return [self._build(item, (*path, i)) for i, item in enumerate(node.value)]
        if isinstance(node, MappingNode):
            return self._mapping(node, path)
        raise self.error_type(f"{self._mk(node)}: unsupported YAML node")

    def _scalar(self, node: ScalarNode) -> Any:
        value = node.value
        if node.tag == _PLAIN:
            return parse_scalar(value)
        if node.tag == _STR:
            return value
        tags: dict[str, Callable[[str], Any]] = {
            "tag:yaml.org,2002:int": int,
            "tag:yaml.org,2002:float": float,
            "tag:yaml.org,2002:bool": lambda v: _BOOLS[v],
            "tag:yaml.org,2002:null": lambda v: None,
        }
        convert = tags.get(node.tag)
        if convert is None:
            raise self.error_type(f"{self._mk(node)}: unsupported YAML tag {node.tag!r} (plain data only)")
        try:
            return convert(value)
        except (ValueError, KeyError):
            raise self.error_type(f"{self._mk(node)}: {value!r} is not a valid {node.tag.rpartition(':')[2]}") from None

    def _mapping(self, node: MappingNode, path: Path_) -> dict[str, Any]:
        out: dict[str, Any] = {}
        merged: dict[str, Any] = {}
        for key_node, value_node in node.value:
            if isinstance(key_node, ScalarNode) and key_node.tag == _MERGE:
                # `<<: *defaults` (or a list of them): their keys apply unless this mapping sets them itself
                sources = value_node.value if isinstance(value_node, SequenceNode) else [value_node]
                for src in sources:
                    if not isinstance(src, MappingNode):
                        raise self.error_type(f"{self._mk(src)}: a merge key `<<` takes a mapping or a list of them")
                    for k, v in self._mapping(src, path).items():
                        merged.setdefault(k, v)
                continue
            if not isinstance(key_node, ScalarNode) or key_node.tag not in (_PLAIN, _STR):
                raise self.error_type(f"{self._mk(key_node)}: mapping keys must be plain strings")
            key = key_node.value
            if key in out:
                first = self.key_marks[(*path, key)]
                raise self.error_type(f"{self._mk(key_node)}: duplicate key {key!r} (first at line {first.line})")
            self.key_marks[(*path, key)] = self._mk(key_node)
            out[key] = self._build(value_node, (*path, key))
        self.value_marks[path] = self._mk(node)
        return {**{k: v for k, v in merged.items() if k not in out}, **out}
