"""Typed node parameters: a node declares ``class Params(palpa.Params)`` with defaults; values come from the
command line or a launch file and are validated (types, unknown names) before the node runs."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, get_args, get_origin

import msgspec

from palpa.errors import ParamError
from yamlstruct import Source, YamlError, convert, did_you_mean

__all__ = [
    "Change", "InputPath", "NonNegative", "Params", "Positive", "PositiveInt", "RunTime", "SafetyLimit", "change_rules",
    "convert_params", "describe_params", "input_paths", "parse_param_value", "read_params_file",
]

P = TypeVar("P", bound="Params")
T = TypeVar("T")

# Physical bounds declared in the type: a launch file's --check and a node's start refuse a value outside them
# (naming file:line and the parameter) before anything runs. NaN and infinity fail them too.
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=sys.float_info.max)]
"""A finite float > 0 (a rate, a speed, a period, a size)."""
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=sys.float_info.max)]
"""A finite float >= 0 (a set-point, a clearance, a delay that may be zero)."""
PositiveInt = Annotated[int, msgspec.Meta(gt=0)]

InputPath = Annotated[str, msgspec.Meta(extra={"palpa": "input path"})]
"""A ``str`` parameter naming a file or folder the node reads ('' = not given): ``palpa launch --check`` (and
every launch) checks that it exists before any node starts."""


# When a parameter may change (palpa.node.params_runtime): by default only at launch, since a node that does not apply a
# change must not acknowledge one. The node declares what it applies while it runs; a safety limit never changes.
_CHANGE_KEY = "palpa change"
Change = Literal["run time", "launch", "safety limit"]
"""When a parameter may change: ``run time`` (``palpa param set``; the node applies it), ``launch`` (the default:
fixed once the node runs), ``safety limit`` (fixed at launch, and no declaration can make it changeable)."""

RunTime = Annotated[T, msgspec.Meta(extra={_CHANGE_KEY: "run time"})]
"""A parameter the node applies when it changes while it runs (``palpa param set``): its ``on_params_changed``
takes the new value, or the node reads ``self.params`` afresh every time it uses it. Written around the type:
``rate_hz: palpa.RunTime[palpa.Positive] = 10.0``. Parameters without it are fixed at launch and a change is
refused."""
SafetyLimit = Annotated[T, msgspec.Meta(extra={_CHANGE_KEY: "safety limit"})]
"""A safety limit (a workspace box, a speed or pressure cap, a watchdog): fixed at launch, and a run-time change is
refused saying so (``workspace_mm: palpa.SafetyLimit[tuple[float, ...]] = ...``)."""


def _change_rule(name: str, tp: Any) -> Change:
    marks = {(m.extra or {}).get(_CHANGE_KEY) for m in get_args(tp)[1:] if isinstance(m, msgspec.Meta)} \
        if get_origin(tp) is Annotated else set()
    marks.discard(None)
    if marks == {"run time", "safety limit"}:
        raise TypeError(f"parameter {name!r} is declared both RunTime and SafetyLimit: a safety limit is fixed "
                        "at launch")
    return "safety limit" if "safety limit" in marks else "run time" if marks else "launch"


def change_rules(cls: type[Params]) -> dict[str, Change]:
    """Parameter name -> when it may change (:data:`Change`), from the declaration (:data:`RunTime`,
    :data:`SafetyLimit`; undeclared: ``launch``)."""
    return {f.name: _change_rule(f.name, f.type) for f in msgspec.structs.fields(cls)}


def _is_input_path(tp: Any) -> bool:
    return get_origin(tp) is Annotated and any(
        isinstance(m, msgspec.Meta) and (m.extra or {}).get("palpa") == "input path" for m in get_args(tp)[1:])


def input_paths(params: Params) -> dict[str, str]:
    """Name -> value of every non-empty :data:`InputPath` parameter of ``params``."""
    return {f.name: getattr(params, f.name) for f in msgspec.structs.fields(type(params))
            if _is_input_path(f.type) and getattr(params, f.name)}


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
        declared = tuple(describe_params(cls))
        # msgspec says "... - at `$.name`": turn the JSON path into a parameter name.
        if " - at `$." in text:
            what, _, path = text.rpartition(" - at `$.")
            path = path.rstrip("`")
            raise ParamError(f"{where}: parameter {path!r}: {what}", param=path.split(".")[0].split("[")[0],
                             reason=what, declared=declared) from None
        if text.startswith("Object contains unknown field"):
            unknown = text.rpartition(" ")[2].strip("`")
            raise ParamError(f"{where}: {text}{did_you_mean(unknown, declared)} (declared parameters: "
                             f"{', '.join(declared) or 'none'})", param=unknown, reason=text, unknown=True,
                             declared=declared) from None
        raise ParamError(f"{where}: {text}", reason=text, declared=declared) from None


def read_params_file(path: Path, what: str, params_type: type[Params] | None = None) -> dict[str, Any]:
    """A YAML mapping of parameter names to values (``--params-file``, ``palpa param load``); raises
    :class:`ParamError` starting with ``what`` when the file cannot be read or is not a mapping, and, given the
    node's ``params_type``, at the ``file:line:col`` of a name it does not declare or a value of the wrong type."""
    try:
        src = Source.read(path)  # the one YAML reader (YAML 1.2 scalars, duplicate keys refused), with file:line
        if not isinstance(src.data, dict):
            raise src.error((), "expected a mapping of parameters")
        if params_type is not None:
            _check_values(src, params_type)
    except YamlError as exc:
        raise ParamError(f"{what}: {exc}") from None
    return src.data


def _check_values(src: Source, cls: type[Params]) -> None:
    """Each value of the mapping ``src`` against its field of ``cls`` (the file may give only some of them)."""
    fields = {f.name: f.type for f in msgspec.structs.fields(cls)}
    owner = cls.__qualname__.removesuffix(".Params")
    for name, value in src.data.items():
        if name not in fields:
            raise src.error((name,), f"node class {owner} has no parameter {name!r}{did_you_mean(name, fields)}; "
                                     f"declared: {', '.join(fields) or 'none'}", key=True)
        convert(src, value, fields[name], (name,))


def parse_param_value(text: str, what: str) -> Any:
    """A parameter value typed on a command line (``-p name=VALUE``, ``palpa param set``), read as YAML by the
    project's one reader (YAML 1.2: ``yes`` stays a string); an empty text is the empty string."""
    if not text:
        return ""
    try:
        return Source.from_text(text, what).data
    except YamlError as exc:
        raise ParamError(str(exc)) from None


def describe_params(cls: type[Params]) -> dict[str, str]:
    """Parameter name -> 'type = default' text, for --help and ``launch --check``."""
    out: dict[str, str] = {}
    for field in msgspec.structs.fields(cls):
        default = "required" if field.required else repr(
            field.default if field.default is not msgspec.NODEFAULT else field.default_factory()
        )
        tp = get_args(field.type)[0] if get_origin(field.type) is Annotated else field.type  # bounds: the base
        tname = "path" if _is_input_path(field.type) else getattr(tp, "__name__", None) or str(tp)
        out[field.name] = f"{tname} = {default}"
    return out
