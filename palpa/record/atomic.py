"""Outputs written beside their place and renamed into it (``bag export``, ``bag edit``, the table export): a
failure, or a kill, leaves no half-written output under the name asked for."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

__all__ = ["remove_path", "written_beside"]


@contextlib.contextmanager
def written_beside(output: Path, *, over_directory: bool = False) -> Iterator[Path]:
    """Yield ``<output>.partial`` (a stale one from a killed run removed first) to write the result to, a file or a
    directory; when the block ends without error it is renamed to ``output``, and whatever happened nothing of it
    is left behind. ``over_directory``: whatever is at ``output`` is removed first (a directory cannot be renamed
    over, nor a file over a directory); without it a file is replaced in one step and a directory is an error."""
    tmp = output.with_name(output.name + ".partial")
    remove_path(tmp)
    try:
        yield tmp
        if over_directory:
            remove_path(output)
        os.replace(tmp, output)
    finally:
        remove_path(tmp)


def remove_path(path: Path) -> None:
    """Remove the file or the directory tree at ``path``, if there is one (a symlink itself, not what it points to)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
