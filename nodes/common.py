"""Small helpers shared by the palpation nodes."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from models.phantom import Phantom, load_phantom

__all__ = ["phantom_from_param"]


@lru_cache(maxsize=8)
def _load(path: str) -> Phantom:
    return load_phantom(path)


def phantom_from_param(path: str, node: str) -> Phantom:
    """Load the phantom named by a node's ``phantom`` parameter; a missing one is a clear error."""
    if not path:
        raise ValueError(f"{node}: the sim driver needs the 'phantom' parameter (a phantom YAML file)")
    if not Path(path).is_file():
        raise ValueError(f"{node}: phantom file {path!r} does not exist")
    return _load(path)
