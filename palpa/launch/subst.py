"""Substitutions in launch-file strings (see the table in docs/launch.md).

* ``$(arg NAME)``            the arg's value; a string that is exactly this keeps the value's YAML type
* ``$(env NAME)``            an environment variable (an error if unset); ``$(env NAME default words)`` otherwise
* ``$(dirname)``             the folder of the launch file being read (absolute)
* ``$(run_dir)``             the run directory
* ``$(recorded ARG NODE PARAM)``  param PARAM of node NODE in the launch that made the recording named by arg ARG
  (a replay takes the recorded scan's settings instead of a default that fits only the demo)
* ``$$(``                    a literal ``$(``
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from palpa.errors import LaunchError
from palpa.launch.source import Path_, Source
from palpa.launch.validate import did_you_mean

__all__ = ["substitute"]

_SUBST_RE = re.compile(r"\$\$\(|\$\(([^()]*)\)|\$\(")


def substitute(src: Source, value: Any, path: Path_, args: Mapping[str, Any], run_dir: Path) -> Any:
    """``value`` (any YAML data from ``src`` at ``path``) with every substitution in its strings applied."""
    if isinstance(value, str):
        return _subst_str(src, value, path, args, run_dir)
    if isinstance(value, list):
        return [substitute(src, v, (*path, i), args, run_dir) for i, v in enumerate(value)]
    if isinstance(value, dict):
        return {k: substitute(src, v, (*path, k), args, run_dir) for k, v in value.items()}
    return value


def _subst_str(src: Source, text: str, path: Path_, args: Mapping[str, Any], run_dir: Path) -> Any:
    if "$(" not in text:
        return text
    whole = re.fullmatch(r"\$\(\s*arg\s+([^()\s]+)\s*\)", text)
    if whole:
        return _arg(src, path, whole.group(1), args)
    out: list[str] = []
    pos = 0
    for m in _SUBST_RE.finditer(text):
        out.append(text[pos:m.start()])
        pos = m.end()
        token = m.group(0)
        if token == "$$(":
            out.append("$(")
        elif token == "$(":
            raise src.error(path, f"unterminated substitution in {text!r}: expected $(...) with a closing ')' "
                                  "(write $$( for a literal '$(')")
        else:
            value = _evaluate(src, path, m.group(1), args, run_dir)
            out.append(value if isinstance(value, str) else json.dumps(value))
    out.append(text[pos:])
    return "".join(out)


def _evaluate(src: Source, path: Path_, expr: str, args: Mapping[str, Any], run_dir: Path) -> Any:
    words = expr.split()
    kind = words[0] if words else ""
    if kind == "arg" and len(words) == 2:
        return _arg(src, path, words[1], args)
    if kind == "env" and len(words) >= 2:
        value = os.environ.get(words[1])
        if value is not None:
            return value
        if len(words) > 2:
            return " ".join(words[2:])
        raise src.error(path, f"environment variable {words[1]!r} is not set and $(env {words[1]}) has no "
                              f"default (write $(env {words[1]} DEFAULT))")
    if kind == "dirname" and len(words) == 1:
        return str(src.path.parent)
    if kind == "run_dir" and len(words) == 1:
        return str(run_dir)
    if kind == "recorded" and len(words) == 4:
        return _recorded(src, path, words[1], words[2], words[3], args)
    raise src.error(path, f"unknown substitution $({expr}): expected $(arg NAME), $(env NAME [DEFAULT]), "
                          "$(dirname), $(run_dir) or $(recorded ARG NODE PARAM)")


def _recorded(src: Source, path: Path_, arg: str, node: str, param: str, args: Mapping[str, Any]) -> Any:
    """The value ``param`` had for ``node`` in the launch file attached to the recording named by arg ``arg``."""
    from palpa.record.format import BagError
    from palpa.record.reader import launch_text_of

    bag = _arg(src, path, arg, args)
    name = src.get((*path[:2], "name")) if path[:1] == ("args",) else None
    how = f"give {name}:=VALUE instead" if isinstance(name, str) else "give the value in the launch file instead"
    try:
        text = launch_text_of(str(bag))
    except BagError as exc:
        raise src.error(path, f"$(recorded {arg} {node} {param}): {exc}") from None
    if text is None:
        raise src.error(path, f"$(recorded {arg} {node} {param}): {bag} carries no launch file (it was not "
                              f"recorded by a launch); {how}")
    try:
        # read as the launch read it (YAML 1.2 scalars: a recorded `yes` is the string it was then)
        nodes = (Source.from_text(text, str(bag)).data or {}).get("nodes") or []
        entry = next(n for n in nodes if isinstance(n, dict) and n.get("name") == node)
        return entry["params"][param]
    except (LaunchError, AttributeError, StopIteration, KeyError, TypeError):
        raise src.error(path, f"$(recorded {arg} {node} {param}): the launch that made {bag} gave node {node!r} "
                              f"no param {param!r}; {how}") from None


def _arg(src: Source, path: Path_, name: str, args: Mapping[str, Any]) -> Any:
    if name in args:
        return args[name]
    if path[:1] == ("args",):
        raise src.error(path, f"$(arg {name}): not declared before this arg (an arg's default may only use "
                              f"args declared above it)")
    names = ", ".join(args) or "none"
    raise src.error(path, f"$(arg {name}): no such arg{did_you_mean(name, args)} (declared: {names})")
