"""Runtime parameters: read and change a running node's ``Params`` through two services every node serves.

``_palpa/param/<node>/get`` (:class:`ParamGet` -> :class:`ParamValues`) and ``_palpa/param/<node>/set``
(:class:`ParamSet` -> :class:`ParamValues`). A set merges the given values into the current ones and validates
the whole set with msgspec, as at launch (an error names the parameter: ``parameter 'rate_hz': Expected `float`,
got `str```). Only parameters declared :data:`palpa.RunTime` may change: a change of any other is refused, naming
it (a :data:`palpa.SafetyLimit` as a safety limit fixed at launch), and nothing changes; a node never acknowledges a
change it does not apply. The node's ``on_params_changed(old, new)`` may then refuse it (return False or raise
ParamError). An accepted change replaces the node's ``params`` at once and is published on ``_palpa/params``
(:class:`ParamChange`), which the recorder keeps like the log. ``palpa param list|get|set|dump NODE`` is the command
line.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import msgspec

from palpa.errors import ParamError
from palpa.message import Message
from palpa.node.params import (
    Change,
    Params,
    change_rules,
    convert_params,
    describe_params,
    param_docs,
)
from palpa.node.service import RequestRefused

if TYPE_CHECKING:
    from palpa.node.nodeapi import NodeApi

__all__ = ["PARAMS_TOPIC", "ParamChange", "ParamGet", "ParamServer", "ParamSet", "ParamValues", "param_service"]

PARAMS_TOPIC = "_palpa/params"


def param_service(node: str, verb: str) -> str:
    """The name of node ``node``'s parameter service ``verb`` (``get`` or ``set``)."""
    return f"_palpa/param/{node}/{verb}"


class ParamGet(Message, frozen=True, kw_only=True):
    """Ask a node for its parameters."""


class ParamSet(Message, frozen=True, kw_only=True):
    """Change some of a node's parameters (name -> new value); the others keep theirs."""

    values: dict[str, Any]


class ParamValues(Message, frozen=True, kw_only=True):
    """A node's parameters: name -> value, name -> 'type = default' (what ``palpa param list`` shows), name ->
    when it may change (``run time``, ``launch`` or ``safety limit``: palpa.node.params.Change), and name -> its
    description and bounds (``palpa param describe``); the last two empty from a node older than them."""

    node: str
    values: dict[str, Any]
    types: dict[str, str]
    change: dict[str, str] = {}
    docs: dict[str, str] = {}


class ParamChange(Message, frozen=True, kw_only=True):
    """An accepted runtime change (topic ``_palpa/params``): the new and the previous values of what changed."""

    node: str
    stamp_ns: int
    changed: dict[str, Any]
    previous: dict[str, Any]


class ParamServer:
    """Serves a node's parameter services (made by the node when it announces itself on the graph).

    ``current()`` is the node's parameters now; ``change(old, new)`` asks the node to take ``new`` (False, or a
    raised :class:`ParamError`, refuses it) and replaces its parameters when it does."""

    def __init__(self, node: NodeApi, current: Callable[[], Params],
                 change: Callable[[Params, Params], bool]) -> None:
        self.node = node
        self.current = current
        self.change = change
        self._changes = node.publisher(PARAMS_TOPIC, ParamChange)
        node.service(param_service(node.name, "get"), ParamGet, ParamValues, self.on_get)
        node.service(param_service(node.name, "set"), ParamSet, ParamValues, self.on_set)

    def values(self) -> ParamValues:
        node = self.node
        params = self.current()
        types, rules, docs = self._described(type(params))
        return ParamValues(node=node.name, values=msgspec.to_builtins(params), types=dict(types),
                           change=dict(rules), docs=docs)

    _described_cache: dict[type[Params], tuple[dict[str, str], dict[str, Change], dict[str, str]]] = {}

    @classmethod
    def _described(cls, params_type: type[Params]) -> tuple[dict[str, str], dict[str, Change], dict[str, str]]:
        """The types and defaults, change rules and docs of ``params_type``'s parameters: made once per class (its
        fields are fixed when the class is made; the docs are read from its source), not at every get and set."""
        described = cls._described_cache.get(params_type)
        if described is None:
            described = cls._described_cache[params_type] = (
                describe_params(params_type), change_rules(params_type), param_docs(params_type))
        return described

    def on_get(self, req: ParamGet) -> ParamValues:
        return self.values()

    def on_set(self, req: ParamSet) -> ParamValues:
        node = self.node
        old = self.current()
        current: dict[str, Any] = msgspec.to_builtins(old)
        unknown = sorted(set(req.values) - set(current))
        if unknown:
            raise ParamError(f"node {node.name!r}: no parameter {', '.join(map(repr, unknown))} "
                             f"(declared: {', '.join(current) or 'none'})")
        new = convert_params(type(old), {**current, **req.values}, where=f"node {node.name!r}")
        after: dict[str, Any] = msgspec.to_builtins(new)
        changed = {k: v for k, v in after.items() if v != current[k]}
        _refuse_fixed(node.name, changed, self._described(type(old))[1])
        if changed:
            try:
                accepted = self.change(old, new)
            except ParamError as exc:
                raise RequestRefused(str(exc)) from None
            if not accepted:
                raise RequestRefused(f"node {node.name!r} refused the change of {', '.join(changed)}")
            node.log.info("parameters changed: %s", ", ".join(f"{k}={v!r}" for k, v in changed.items()))
            self._changes.publish(ParamChange(node=node.name, stamp_ns=node.clock.now_ns(), changed=changed,
                                              previous={k: current[k] for k in changed}))
        return self.values()


def _refuse_fixed(node: str, changed: dict[str, Any], rules: Mapping[str, str]) -> None:
    """Raise :class:`RequestRefused` when ``changed`` holds a parameter that may not change at run time (safety
    limits named first); the message says what may change instead."""
    limits = sorted(k for k in changed if rules.get(k) == "safety limit")
    if limits:
        what = "is a safety limit" if len(limits) == 1 else "are safety limits"
        raise RequestRefused(f"node {node!r}: {_names(limits)} {what}, fixed at launch: change it in the launch "
                             "file and start the node again (nothing was changed)")
    fixed = sorted(k for k in changed if rules.get(k) != "run time")
    if fixed:
        live = [k for k, rule in rules.items() if rule == "run time"]
        what = "is" if len(fixed) == 1 else "are"
        raise RequestRefused(f"node {node!r}: {_names(fixed)} {what} fixed at launch (the node does not "
                             f"apply a change while it runs; it may change: {', '.join(live) or 'none'}); nothing "
                             "was changed")


def _names(names: list[str]) -> str:
    return ("parameter " if len(names) == 1 else "parameters ") + ", ".join(map(repr, names))
