"""Typed messages: the shared base, the registry (type name <-> Struct) and JSON Schema export.

Every message is a frozen, keyword-only ``msgspec.Struct`` deriving from :class:`Message`. Defining the subclass
registers it under its type name (the class name, or ``type_name`` if the class sets it), which is what travels
in the envelope header so that tools (``topic echo``, ``bag info``, other languages) can decode without guessing.

Evolution policy (see docs/wire.md): add fields only with defaults; never reuse, rename or retype a field name;
never reuse a type name for a different meaning. Decoders ignore unknown fields, so old readers keep working.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any, ClassVar, TypeVar

import msgspec

from palpa.errors import RegistryError
from yamlstruct import did_you_mean

__all__ = ["Finite", "Message", "json_schema", "lookup", "registered"]

_REGISTRY: dict[str, type[Message]] = {}

Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]
"""A float that must be finite: NaN and ±inf fail validation at decode (a NaN compares false with both bounds).
Use it for every field where a non-finite number makes no sense (a set-point, a rate, a pose); plain ``float``
stays for fields where NaN means "no data" (a map cell, an invalid sample's value)."""

M = TypeVar("M", bound="Message")


class Message(msgspec.Struct, frozen=True, kw_only=True):
    """Base of all bus messages: frozen, keyword-only, encoded as a msgpack map of field name to value."""

    type_name: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        name = cls.__dict__.get("type_name") or cls.__name__
        cls.type_name = name
        existing = _REGISTRY.get(name)
        if existing is not None and existing is not cls and (
            existing.__module__,
            existing.__qualname__,
        ) != (cls.__module__, cls.__qualname__):
            raise RegistryError(
                f"message type name {name!r} is already taken by "
                f"{existing.__module__}.{existing.__qualname__}; set type_name to a unique name"
            )
        _REGISTRY[name] = cls


def lookup(name: str) -> type[Message]:
    """The message class registered under ``name``; raises :class:`RegistryError` when none is."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise RegistryError(
            f"unknown message type {name!r}{did_you_mean(name, _REGISTRY)} (is the module that defines it "
            "imported? `palpa schema --list` lists the known ones)"
        ) from None


def registered() -> dict[str, type[Message]]:
    """A copy of the registry: every message type known to this process, by name."""
    return dict(_REGISTRY)


def json_schema(cls: type[Message]) -> dict[str, Any]:
    """JSON Schema (draft 2020-12) of one message type, with its wire name as ``title``."""
    schema: dict[str, Any] = msgspec.json.schema(cls)
    schema.setdefault("title", cls.type_name)
    schema["x-palpa-type"] = cls.type_name
    return schema
