"""A launch file read as YAML with the marks of every key and value: :class:`yamlstruct.Source` raising
:class:`LaunchError` (the reader itself is shared with parameter files and calibrations, see :mod:`yamlstruct`)."""

from __future__ import annotations

from typing import ClassVar

from palpa.errors import LaunchError
from yamlstruct.source import Mark, Path_, display_path, parse_scalar
from yamlstruct.source import Source as _Source

__all__ = ["Mark", "Path_", "Source", "display_path", "parse_scalar"]


class Source(_Source):
    """One launch file; its errors are :class:`LaunchError`."""

    error_type: ClassVar[type[Exception]] = LaunchError
    document: ClassVar[str] = "the launch file"

    def error(self, path: Path_, message: str, *, key: bool = False) -> LaunchError:
        return LaunchError(f"{self.mark(path, key=key)}: {message}")
