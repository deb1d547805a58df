"""Outputs written beside their place and renamed into it: a failure, or a kill, leaves no half-written output
under the name asked for, and a reader sees the old output or the new one, never a part.

The one implementation of write-then-rename in the project (bag export and edit, the table export, a launch's
``bus.address`` and its entry among the running launches, the map's files, the sweep's results and tables). It
imports nothing of palpa, so any layer may use it. It does not fsync: a rename survives a crash of the writer, not
a crash of the machine."""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

__all__ = ["remove_path", "write_beside", "written_beside"]


@contextlib.contextmanager
def written_beside(output: Path, *, over_directory: bool = False, per_writer: bool = False) -> Iterator[Path]:
    """Yield a path beside ``output`` to write the result to (a file, a directory or a symlink, by any writer:
    ``open``, ``np.savez``, ``pq.write_table``); when the block ends without error it is renamed to ``output``,
    and whatever happened nothing of it is left behind.

    The path is ``<output>.partial``, a stale one from a killed run removed first: one writer per output.
    ``per_writer``: for outputs that several processes or threads may write at once (the last rename wins), the
    path is ``.<name>.<pid>-<thread>.partial``, the writer's own, and a killed writer's is left (hidden) where it
    was. ``over_directory``: whatever is at ``output`` is removed first (a directory cannot be renamed over, nor
    a file over a directory); without it a file or a symlink is replaced in one step and a directory is an error.
    """
    if per_writer:
        tmp = output.with_name(f".{output.name}.{os.getpid()}-{threading.get_ident()}.partial")
    else:
        tmp = output.with_name(output.name + ".partial")
        remove_path(tmp)
    try:
        yield tmp
        if over_directory:
            remove_path(output)
        os.replace(tmp, output)
    finally:
        remove_path(tmp)


def write_beside(output: Path, data: str | bytes, *, per_writer: bool = False) -> None:
    """Write ``data`` (text as UTF-8) to ``output`` whole or not at all (:func:`written_beside`)."""
    with written_beside(output, per_writer=per_writer) as tmp:
        if isinstance(data, str):
            tmp.write_text(data, encoding="utf-8")
        else:
            tmp.write_bytes(data)


def remove_path(path: Path) -> None:
    """Remove the file or the directory tree at ``path``, if there is one (a symlink itself, not what it points to)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
