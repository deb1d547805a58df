"""A guard on palpa.Node's own state: a subclass whose ``setup`` assigns one of the names the node keeps its
timers, sockets or receiver in breaks the node in a way that shows only later, and far from the cause; the guard
says so when ``setup`` returns."""

from __future__ import annotations

from collections.abc import Mapping

from palpa.errors import PalpaError

__all__ = ["check_state_kept", "own_state"]


def own_state(node: object, theirs: set[str]) -> dict[str, object]:
    """The private state objects palpa.Node's constructor made (not flags and counters, which change; not what the
    subclass set before it)."""
    return {k: v for k, v in vars(node).items()
            if k.startswith("_") and k not in theirs and not isinstance(v, bool | int | float | str)}


def check_state_kept(node: object, name: str, own: Mapping[str, object]) -> None:
    """Raise :class:`PalpaError` when node ``name``'s ``setup`` replaced one of ``own`` (:func:`own_state`)."""
    for k, v in own.items():
        if vars(node).get(k) is not v:
            raise PalpaError(f"node {name!r}: {type(node).__name__}.setup() replaced {k!r}, which palpa.Node "
                             "keeps its own state in; give your attribute another name")
