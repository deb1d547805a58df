"""The exception tree of the runtime.

Every expected failure a user can cause (a bad launch file, a wrong parameter, an unreachable bus) raises a
subclass of :class:`PalpaError`; the CLI prints its message as one line and exits 1. Anything else is a bug.
"""

from __future__ import annotations

__all__ = [
    "BusError",
    "DecodeError",
    "LaunchError",
    "PalpaError",
    "ParamError",
    "RegistryError",
]


class PalpaError(Exception):
    """Base of every error the runtime raises on purpose."""


class RegistryError(PalpaError):
    """A message type name is unknown, or two types claim the same name."""


class DecodeError(PalpaError):
    """A frame could not be decoded into the expected type; the message says which field and why."""


class ParamError(PalpaError):
    """A node parameter is missing, unknown or of the wrong type.

    When validation found it, :attr:`param` names the parameter, :attr:`reason` says what was wrong with it,
    :attr:`unknown` tells a name the node does not declare, and :attr:`declared` lists the names it does (so a
    launch file can point at the key without re-reading the message)."""

    def __init__(self, message: str, *, param: str = "", reason: str = "", unknown: bool = False,
                 declared: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.param, self.reason, self.unknown, self.declared = param, reason, unknown, declared


class BusError(PalpaError):
    """The bus address is malformed or the bus cannot be reached or started."""


class LaunchError(PalpaError):
    """A launch file is invalid or a launched graph failed."""
