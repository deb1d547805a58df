"""How a node runs its callbacks: exception isolation, callback depth, and the batches flushed when it returns.

One :class:`Dispatch` per node. Everything that calls user code (subscriptions, raw subscriptions, timers, service
handlers, service-call completions) goes through it, so that a failing callback is counted and logged the same way
everywhere and the messages published inside a callback leave together when the outermost callback returns.
Publishers only need :meth:`Dispatch.inside` and :meth:`Dispatch.pending`; they never see the node.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Callable
from typing import Protocol

__all__ = ["Dispatch", "Flushable", "Spinner"]


class Flushable(Protocol):
    """Something holding a batch to send (a publisher)."""

    def flush(self) -> None: ...


class Spinner(Protocol):
    """What a blocking wait on an endpoint needs from its node: run the loop, and know when to give up."""

    @property
    def is_shutdown(self) -> bool: ...

    def spin_once(self, timeout_s: float = 0.0) -> None: ...


class Dispatch:
    """Runs callbacks for one node; publishers register their pending batches here."""

    def __init__(self, log: logging.Logger) -> None:
        self.log = log
        self.depth = 0
        """How many callbacks are running (nested: a callback waiting on a service call runs others)."""
        self.errors = 0
        """Callbacks that raised (each logged with its traceback)."""
        self._pending: list[Flushable] = []

    @property
    def inside(self) -> bool:
        """Whether a callback is running (publishers batch then)."""
        return self.depth > 0

    def call(self, fn: Callable[..., object], *args: object) -> None:
        """``fn(*args)`` as one callback: never raises; pending batches leave when the outermost one returns."""
        self.depth += 1
        try:
            fn(*args)
        except Exception:
            self.failed(fn)
        finally:
            self.depth -= 1
        if self._pending and not self.depth:
            self.flush()

    def call_each(self, fn: Callable[[int], object], n: int, name: object) -> None:
        """``fn(0) .. fn(n-1)`` as one callback scope (a batch of messages): a failing call is counted under
        ``name`` and skipped, the rest go on; batches leave once, after the last."""
        self.depth += 1
        start = 0
        try:
            while start < n:
                # one try per run of good calls, not per call
                i = start
                try:
                    for i in range(start, n):
                        fn(i)
                    start = n
                except Exception:
                    self.failed(name)
                    start = i + 1
        finally:
            self.depth -= 1
        if self._pending and not self.depth:
            self.flush()

    def failed(self, fn: object) -> None:
        """Count and log the exception being handled; a failing callback never stops the node."""
        self.errors += 1
        self.log.error("error in %s:\n%s", getattr(fn, "__qualname__", fn), traceback.format_exc())

    def pending(self, pub: Flushable) -> None:
        """``pub`` started a batch: flush it when the callbacks return (or at :meth:`flush`)."""
        self._pending.append(pub)

    def flush(self) -> None:
        """Send every batch still pending."""
        pending, self._pending = self._pending, []
        for pub in pending:
            pub.flush()
