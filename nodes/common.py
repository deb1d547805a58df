"""Small helpers shared by the palpation nodes."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from models.camera_calibration import CalibrationError, ProbeCalibration
from models.camera_calibration import load_probe_calibration as read_probe_calibration
from models.phantom import Phantom, PhantomError, load_phantom
from palpa.errors import ParamError

__all__ = ["load_probe_calibration", "phantom_from_param"]


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


def load_probe_calibration(path: str, node: str) -> ProbeCalibration:
    """Read a camera-probe calibration file (YAML, nodes/camera_calibrate.py writes it); a missing or invalid one
    is a :class:`ParamError` naming the file."""
    if not Path(path).is_file():
        raise ParamError(f"{node}: calibration file {path!r} does not exist")
    try:
        return read_probe_calibration(path)
    except CalibrationError as exc:
        raise ParamError(f"{node}: {exc}") from None
