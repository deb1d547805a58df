"""Typed node parameters: a node declares ``class Params(palpa.Params)`` with defaults; values come from the
command line or a launch file and are validated (types, unknown names) before the node runs."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

import msgspec

from palpa.errors import ParamError

__all__ = ["NonNegative", "Params", "Positive", "PositiveInt", "convert_params", "describe_params"]

P = TypeVar("P", bound="Params")

# Physical bounds declared in the type: a launch file's --check and a node's start refuse a value outside them
# (naming file:line and the parameter) before anything runs. NaN and infinity fail them too.
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=sys.float_info.max)]
"""A finite float > 0 (a rate, a speed, a period, a size)."""
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=sys.float_info.max)]
"""A finite float >= 0 (a set-point, a clearance, a delay that may be zero)."""
PositiveInt = Annotated[int, msgspec.Meta(gt=0)]


class Params(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Base of a node's parameter set. Subclass it with typed fields and defaults."""


def convert_params(cls: type[P], values: Mapping[str, Any] | P | None, *, where: str) -> P:
    """Validate ``values`` into ``cls``; raises :class:`ParamError` naming the parameter and what was wrong."""
    if isinstance(values, cls):
        return values
    data: dict[str, Any] = dict(values) if isinstance(values, Mapping) else {}
    try:
        return msgspec.convert(data, cls, strict=True)
    except msgspec.ValidationError as exc:
        text = str(exc)
        # msgspec says "... - at `$.name`": turn the JSON path into a parameter name.
        if " - at `$." in text:
            what, _, path = text.rpartition(" - at `$.")
            text = f"parameter {path.rstrip('`')!r}: {what}"
        elif text.startswith("Object contains unknown field"):
            names = ", ".join(describe_params(cls)) or "none"
            text = f"{text} (declared parameters: {names})"
        raise ParamError(f"{where}: {text}") from None


def describe_params(cls: type[Params]) -> dict[str, str]:
    """Parameter name -> 'type = default' text, for --help and ``launch --check``."""
    out: dict[str, str] = {}
    for field in msgspec.structs.fields(cls):
        default = "required" if field.required else repr(
            field.default if field.default is not msgspec.NODEFAULT else field.default_factory()
        )
        tname = getattr(field.type, "__name__", None) or str(field.type)
        out[field.name] = f"{tname} = {default}"
    return out
