"""Small helpers shared by the palpation nodes."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from models.phantom import Phantom, PhantomError, load_phantom
from palpa.errors import ParamError

__all__ = ["phantom_from_param"]


@lru_cache(maxsize=8)
def _load(path: str) -> Phantom:
    return load_phantom(path)


def phantom_from_param(path: str, node: str) -> Phantom:
    """Load the phantom named by a node's ``phantom`` parameter; a missing or invalid one is a
    :class:`ParamError` (one line from ``palpa run``, no traceback)."""
    if not path:
        raise ParamError(f"{node}: the sim driver needs the 'phantom' parameter (a phantom YAML file)")
    if not Path(path).is_file():
        raise ParamError(f"{node}: phantom file {path!r} does not exist")
    try:
        return _load(path)
    except PhantomError as exc:
        raise ParamError(f"{node}: {exc}") from None
