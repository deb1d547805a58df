"""Whether a subscriber's subscriptions have reached its direct publishers (palpa.net.direct), the direct topics' side of
a node's readiness (palpa.node.presence).

A subscription to a direct topic travels on the subscriber's own connection to each publisher's direct socket, not
through the proxy, so the bus's echo of a readiness probe says nothing about it. After each new connection the
subscriber subscribes one more probe, ``_palpa/reach/<token>/<n>``; on that connection it follows every earlier
subscription (one connection delivers in order; subscriptions made before the connect are sent at once when it is
made, the probe after them). A publisher's direct socket answers every such probe it hears with one message whose
payload is its endpoint (:meth:`palpa.net.direct.DirectSocket.drain`): when it comes back, the publisher has the
subscriber's subscriptions, and the answer came the way a message comes.

The subscriber waits (palpa.node.presence) for every publisher the directory named to it: it connects as soon as it is
told (one it cannot connect to, palpa.net.direct logged why, is not waited for), and to know it has been told of all of
them it asks the cache ``PING`` after its ``GET``s and waits for the ``PONG``, which comes after their answers.
Publishers announced later are probed when the subscriber connects to them, and :attr:`DirectReach.reached` lists
every endpoint that answered, in order: the lockstep clock learns of them from the node's acks (ClockAck
``reached``) and counts on a subscriber of a participant's direct topic only once it has reached that participant
(palpa.timing.lockstep). On the wall clock nothing waits for a later publisher (docs/wire.md, *Direct topics*). An
endpoint withdrawn before it answered is not waited for; a stale one (its publisher died without withdrawing)
never answers, and holds the subscriber's readiness until its bounded wait ends.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable, Sequence

import zmq

from palpa.net.direct import REACH_PREFIX, directory_entry

__all__ = ["DirectReach"]

_tokens = itertools.count()


class DirectReach:
    """One subscriber socket's probes of its direct publishers: which endpoints it was told of, which answered."""

    def __init__(self, sub: zmq.Socket[bytes]) -> None:
        self._sub = sub
        self.prefix = REACH_PREFIX + f"{os.getpid()}.{os.urandom(4).hex()}.{next(_tokens)}/".encode()
        """The probes of this socket start with this (a node hands what comes under it to :meth:`answered`)."""
        self._serial = 0
        self._keys: list[bytes] = []
        self._needs: dict[str, int] = {}
        """Endpoint connected to and not yet answered -> the first probe subscribed after its connection."""
        self.reached: dict[str, None] = {}
        """The endpoints that answered, in order (a dict: an ordered set; live, it grows)."""
        self.pongs: set[bytes] = set()
        """The tokens of the cache's ``PONG`` answers (the transport adds them as they come)."""

    def ping(self, to_cache: Callable[[Sequence[bytes]], None]) -> bytes:
        """Ask the cache (through ``to_cache``) for a ``PONG`` after its answers to everything asked so far; returns
        the token :meth:`synced` takes."""
        token = f"{len(self.pongs)}.{time.monotonic_ns()}".encode()
        to_cache([b"PING", token])
        return token

    def synced(self, token: bytes) -> bool:
        """Whether the ``PONG`` for ``token`` came: every directory entry the cache had for us has been read."""
        return token in self.pongs

    def told(self, key: bytes, payload: bytes) -> None:
        """The directory told of (or withdrew) a direct publisher of a topic this node takes: a withdrawn one is
        not waited for (it will not answer; what it sent is on its way)."""
        entry = directory_entry(key, payload)
        if entry is not None and not entry[1]:
            self._needs.pop(entry[0], None)

    def connected(self, endpoint: str) -> None:
        """The subscriber socket just connected to ``endpoint``: probe it (and every other not yet answered)."""
        if endpoint in self.reached:
            return
        self._serial += 1
        key = self.prefix + str(self._serial).encode()
        self._sub.setsockopt(zmq.SUBSCRIBE, key)
        self._keys.append(key)
        self._needs[endpoint] = self._serial

    def answered(self, topic: bytes, endpoint: str) -> None:
        """A publisher's answer to probe ``topic``: ``endpoint`` has every subscription made before that probe."""
        try:
            serial = int(topic[len(self.prefix):])
        except ValueError:
            return
        need = self._needs.get(endpoint)
        if need is None or need > serial:
            return
        del self._needs[endpoint]
        self.reached[endpoint] = None
        if not self._needs:  # no probe is waited for: stop receiving their answers
            for old in self._keys:
                self._sub.setsockopt(zmq.UNSUBSCRIBE, old)
            self._keys.clear()

    def pending(self) -> list[str]:
        """The endpoints connected to that have not answered."""
        return list(self._needs)
