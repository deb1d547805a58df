"""Small helpers shared by the palpation nodes."""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from models.phantom import Phantom, PhantomError, load_phantom
from palpa.errors import ParamError

if TYPE_CHECKING:
    from models.camera_calibration import ProbeCalibration

__all__ = ["load_probe_calibration", "phantom_from_param"]

T = TypeVar("T")


@lru_cache(maxsize=8)
def _load(path: str) -> Phantom:
    return load_phantom(path)


def _read_as_param(path: str, node: str, what: str, read: Callable[[str], T],
                   errors: type[Exception]) -> T:
    """``read(path)``, with a missing file or ``errors`` turned into a :class:`ParamError` naming the node
    (one line from ``palpa run``, no traceback)."""
    if not Path(path).is_file():
        raise ParamError(f"{node}: {what} file {path!r} does not exist")
    try:
        return read(path)
    except errors as exc:
        raise ParamError(f"{node}: {exc}") from None


def phantom_from_param(path: str, node: str) -> Phantom:
    """Load the phantom named by a node's ``phantom`` parameter (only simulated drivers have one)."""
    if not path:
        raise ParamError(f"{node}: the sim driver needs the 'phantom' parameter (a phantom YAML file)")
    return _read_as_param(path, node, "phantom", _load, PhantomError)


def load_probe_calibration(path: str, node: str) -> ProbeCalibration:
    """Read a camera-probe calibration file (YAML, tools/camera_calibrate.py writes it)."""
    # imported here: it brings OpenCV (~0.1 s), which every node importing this module paid at start-up
    from models.camera_calibration import CalibrationError
    from models.camera_calibration import load_probe_calibration as read_probe_calibration

    return _read_as_param(path, node, "calibration", read_probe_calibration, CalibrationError)
