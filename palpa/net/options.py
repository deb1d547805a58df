"""The transport options of a node, declared once: a msgspec Struct whose field constraints are the bounds.

The launch schema uses it for a node's ``transport:`` (so a launch file is checked against the same bounds, with
file:line errors), the launcher hands it to a child as one JSON value (``PALPA_TRANSPORT``), and the runner reads
that and applies its command-line flags on top. Constructing it directly checks the same bounds.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from palpa import env as palpa_env
from palpa.errors import BusError
from palpa.net.wire import MAX_MSG_BYTES

__all__ = ["TransportOptions"]


class TransportOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """How a node's sockets queue and wait. Set per node in a launch file (``transport:``), on a node's command
    line (``--sndhwm``, ``--rcvhwm``, ``--busy-poll-us``, ``--direct``), or as one JSON object in
    ``PALPA_TRANSPORT`` (which the launcher sets from the launch file)."""

    sndhwm: Annotated[int, Meta(ge=0, description="messages queued towards the bus before ZeroMQ drops new ones "
                                                  "(seen by subscribers as sequence gaps); 0: no limit")] = 10_000
    rcvhwm: Annotated[int, Meta(ge=0, description="messages queued from the bus before ZeroMQ drops new ones; "
                                                  "0: no limit")] = 10_000
    busy_poll_us: Annotated[int, Meta(ge=0, le=1_000_000, description="spin this long for input before "
                                      "blocking: lower latency in exchange for a busy core; 0: always block")] = 0
    max_msg_bytes: Annotated[int, Meta(ge=1024, description="the largest message this node accepts (bytes, all "
                                       "frames); larger ones are refused and counted")] = MAX_MSG_BYTES
    direct: Annotated[tuple[Annotated[str, Meta(min_length=1)], ...], Meta(
        description="topics (as on the bus, after namespace and remap) this node publishes straight to their "
                    "subscribers instead of through the proxy: lower latency (see palpa.net.direct)")] = ()

    def __post_init__(self) -> None:
        # the bounds are the field annotations above; a decoded value was checked by msgspec already, a
        # constructed one is checked here against the same annotations
        for field in msgspec.inspect.type_info(type(self)).fields:  # type: ignore[attr-defined]
            value = getattr(self, field.name)
            kind = field.type
            while isinstance(kind, msgspec.inspect.Metadata):
                kind = kind.type
            if isinstance(kind, msgspec.inspect.IntType):
                if not isinstance(value, int) or isinstance(value, bool):
                    raise BusError(f"transport option {field.name}: expected an integer, got {value!r}")
                if kind.ge is not None and value < kind.ge:
                    raise BusError(f"transport option {field.name}: expected an integer >= {kind.ge}, got {value!r}")
                if kind.le is not None and value > kind.le:
                    raise BusError(f"transport option {field.name}: expected an integer <= {kind.le}, got {value!r}")
            elif isinstance(value, str) or not isinstance(value, (tuple, list)) or \
                    not all(isinstance(t, str) and t for t in value):
                raise BusError(f"transport option {field.name}: expected a list of topic names, got {value!r}")

    def given(self) -> dict[str, Any]:
        """The options that differ from the defaults (as a launch file would write them)."""
        out: dict[str, Any] = msgspec.json.decode(msgspec.json.encode(self))  # plain data: lists, not tuples
        return out

    def to_env(self) -> dict[str, str]:
        """These options as the one variable :meth:`from_env` reads."""
        return {palpa_env.TRANSPORT: msgspec.json.encode(self).decode()}

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None, **overrides: Any) -> TransportOptions:
        """The options in ``PALPA_TRANSPORT`` (defaults when unset), then the non-None ``overrides`` (command-line
        flags). A malformed or out-of-bounds value is a :class:`BusError` naming the variable and the field."""
        text = palpa_env.get(palpa_env.TRANSPORT, env)
        try:
            base = msgspec.json.decode(text, type=cls) if text else cls()
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            raise BusError(f"{palpa_env.TRANSPORT}={text!r}: {exc}") from None
        given = {k: v for k, v in overrides.items() if v is not None}
        return msgspec.structs.replace(base, **given) if given else base
