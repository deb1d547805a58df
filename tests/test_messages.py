"""Every message type: Hypothesis round trip, plain-msgpack readability, JSON Schema export."""

from __future__ import annotations

from typing import Any

import msgpack
import msgspec
import msgspec.inspect as mi
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import messages  # noqa: F401  (registers the domain types)
import palpa
from palpa.message import Message, json_schema, registered


def strategy(t: mi.Type) -> st.SearchStrategy[Any]:
    """A Hypothesis strategy for a msgspec type description (the subset our messages use)."""
    if isinstance(t, mi.FloatType):
        return st.floats(allow_nan=False, allow_infinity=False, width=64)
    if isinstance(t, mi.BoolType):
        return st.booleans()
    if isinstance(t, mi.IntType):
        return st.integers(min_value=-(2**63), max_value=2**64 - 1)
    if isinstance(t, mi.StrType):
        return st.text(max_size=20)
    if isinstance(t, mi.BytesType):
        return st.binary(max_size=20)
    if isinstance(t, mi.AnyType):  # parameter values (palpa.node.params_runtime): what YAML gives
        return st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.integers(-(2**63), 2**63 - 1),
                         st.text(max_size=10), st.booleans(), st.lists(st.integers(0, 9), max_size=3))
    if isinstance(t, mi.LiteralType):
        return st.sampled_from(t.values)
    if isinstance(t, mi.ListType):
        return st.lists(strategy(t.item_type), max_size=4)
    if isinstance(t, mi.TupleType):
        return st.tuples(*(strategy(x) for x in t.item_types))
    if isinstance(t, mi.DictType):
        return st.dictionaries(strategy(t.key_type), strategy(t.value_type), max_size=3)
    if isinstance(t, mi.StructType):
        return st.builds(t.cls, **{f.name: strategy(f.type) for f in t.fields})
    raise NotImplementedError(f"no strategy for {t!r}")


TYPES = sorted(registered().items())


@pytest.mark.parametrize(("name", "cls"), TYPES, ids=[n for n, _ in TYPES])
def test_round_trip_and_plain_msgpack(name: str, cls: type[Message]) -> None:
    enc = msgspec.msgpack.Encoder()
    dec = msgspec.msgpack.Decoder(cls)

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(strategy(mi.type_info(cls)))
    def check(msg: Message) -> None:
        data = enc.encode(msg)
        assert dec.decode(data) == msg
        plain = msgpack.unpackb(data, raw=False, strict_map_key=False)
        assert isinstance(plain, dict)
        assert set(plain) <= {f.name for f in msgspec.structs.fields(cls)}

    check()


@pytest.mark.parametrize(("name", "cls"), TYPES, ids=[n for n, _ in TYPES])
def test_json_schema(name: str, cls: type[Message]) -> None:
    schema = json_schema(cls)
    assert schema["x-palpa-type"] == name
    assert cls.__name__ in schema["$defs"]  # msgspec names definitions by class; the wire name is the title


def test_messages_are_frozen_and_keyword_only() -> None:
    msg = messages.Text(text="a")
    with pytest.raises(AttributeError):
        msg.text = "b"  # type: ignore[misc]
    with pytest.raises(TypeError):
        messages.Text("a")  # type: ignore[misc]


def test_type_names_are_unique() -> None:
    with pytest.raises(palpa.RegistryError, match="already taken"):

        class Text(palpa.Message, frozen=True, kw_only=True):  # a second "Text" elsewhere
            other: int
