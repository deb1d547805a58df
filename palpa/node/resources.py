"""What a node closes when it closes (:meth:`palpa.node.node.Node.closing`): drivers, ports, files, each closed
once, in reverse order of registration, a failing ``close()`` logged without keeping the others open."""

from __future__ import annotations

import contextlib
import logging
import traceback
from typing import Protocol, TypeVar

__all__ = ["C", "Closable", "Resources"]


class Closable(Protocol):
    """Anything with a ``close()``."""

    def close(self) -> object: ...


C = TypeVar("C", bound=Closable)


class Resources:
    """The resources one node registered, closed together by :meth:`close`."""

    def __init__(self, log: logging.Logger) -> None:
        self._stack = contextlib.ExitStack()
        self._log = log

    def add(self, resource: C) -> C:
        """Close ``resource`` with the others (before those registered earlier); returns it."""
        self._stack.callback(self._close_quietly, resource)
        return resource

    def close(self) -> None:
        """Close every resource registered so far, newest first."""
        self._stack.close()

    def _close_quietly(self, resource: Closable) -> None:
        try:
            resource.close()
        except Exception:
            self._log.error("error closing %r:\n%s", resource, traceback.format_exc())
