"""The recorder's parameters, and what is checked before the recorder touches the bus: the parameters valid, the
launch file to attach readable, the output free (stale split pieces of an earlier run deleted, unless a live
recorder holds one). Split from palpa.record.recorder, which re-exports :class:`RecorderParams`."""

from __future__ import annotations

from pathlib import Path

import palpa
from palpa.errors import ParamError
from palpa.record.format import BagError, split_path, split_pieces
from palpa.record.writer import COMPRESSIONS, lock_many

__all__ = ["RecorderParams", "check_params", "prepare_output"]


class RecorderParams(palpa.Params):
    """Parameters of :class:`palpa.record.recorder.Recorder`."""

    output: str
    """File to write; with splitting, pieces are ``<stem>-0001.mcap``, ``<stem>-0002.mcap``, ..."""
    topics: list[str] = []
    """Regexes matched against whole topic names; empty records every (non-runtime) topic."""
    exclude: list[str] = []
    split_size_mb: float = 0.0
    """Start a new file once this one holds this many MB (1e6 bytes); checked whenever a chunk is closed,
    so a piece can exceed it by up to one chunk (1 MB). 0: never."""
    split_duration_s: float = 0.0
    """Start a new file after this many seconds (checked every flush_period_s); 0: never."""
    force: bool = False
    """Overwrite ``output`` (and stale split pieces of it) if it exists."""
    launch_file: str = ""
    """A resolved launch file to store in the recording as the attachment launch.resolved.yaml."""
    compression: str = "zstd"
    """Chunk compression: zstd, lz4 or none."""
    flush_period_s: float = 0.5
    """Close the open chunk at least this often (s): the most a SIGKILL can lose. At most 1 s."""
    fsync: bool = False
    """Also fsync on every flush (survives power loss, costs disk latency)."""


def check_params(p: RecorderParams, where: str) -> bytes:
    """Refuse (:class:`ParamError`, naming ``where`` and the parameter) what the recorder cannot record with; returns
    the text of ``launch_file`` (b"" without one)."""
    if not p.output:
        raise ParamError(f"{where}: parameter 'output': a file path is required")
    if p.split_size_mb < 0 or p.split_duration_s < 0:
        raise ParamError(f"{where}: split_size_mb and split_duration_s must be >= 0")
    if not 0 < p.flush_period_s <= 1.0:
        raise ParamError(f"{where}: parameter 'flush_period_s' must be in (0, 1] s, got {p.flush_period_s}")
    if p.compression not in COMPRESSIONS:
        raise ParamError(f"{where}: parameter 'compression' must be one of {', '.join(COMPRESSIONS)}")
    if not p.launch_file:
        return b""
    try:
        return Path(p.launch_file).read_bytes()
    except OSError as exc:
        raise ParamError(f"{where}: parameter 'launch_file': cannot read {p.launch_file}: {exc}") from None


def prepare_output(p: RecorderParams, splitting: bool) -> None:
    """Make sure the recording can start at ``p.output`` (its first piece when ``splitting``): its directory exists,
    it is not there already (unless ``force``), and stale split pieces of it are gone (:class:`BagError`)."""
    out = Path(p.output)
    if not out.parent.is_dir():
        raise BagError(f"cannot record to {out}: directory {out.parent} does not exist")
    first = split_path(out, 1) if splitting else out
    if first.exists() and not p.force:
        raise BagError(f"{first} already exists (use --force / force: true to overwrite)")
    if splitting:
        old = split_pieces(out)
        if old and not p.force:
            raise BagError(f"{old[0]} already exists (use --force / force: true to overwrite)")
        # stale pieces of an earlier, longer run would read as part of this one; but a piece a live recorder
        # holds is its data: refuse before deleting any
        held = lock_many(old)
        try:
            for piece in old:
                piece.unlink()
        finally:
            for fh in held:
                fh.close()
