"""Validation of a launch file against its schema: :func:`yamlstruct.convert.convert` with the whole file's type
(:class:`palpa.launch.schema.LaunchFile`) naming the allowed keys."""

from __future__ import annotations

from typing import Any

from palpa.launch.schema import LaunchFile
from palpa.launch.source import Path_, Source
from yamlstruct.convert import convert as _convert
from yamlstruct.convert import did_you_mean, kind, lower_first

__all__ = ["convert", "did_you_mean", "kind", "lower_first"]


def convert(src: Source, data: Any, typ: Any, base: Path_ = ()) -> Any:
    """``data`` (from ``src`` at ``base``) as ``typ``, strictly; a LaunchError at the offending key otherwise."""
    return _convert(src, data, typ, base, root=LaunchFile)
