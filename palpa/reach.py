"""Whether a subscriber's subscriptions have reached its direct publishers (palpa.direct), the direct topics' side of
a node's readiness (palpa.presence).

A subscription to a direct topic travels on the subscriber's own connection to each publisher's direct socket, not
through the proxy, so the bus's echo of a readiness probe says nothing about it. After each new connection the
subscriber subscribes one more probe, ``_palpa/reach/<token>/<n>``; on that connection it follows every earlier
subscription (one connection delivers in order; subscriptions made before the connect are sent at once when it is
made, the probe after them). A publisher's direct socket answers every such probe it hears with one message whose
payload is its endpoint (:meth:`palpa.direct.DirectSocket.drain`): when it comes back, the publisher has the
subscriber's subscriptions, and the answer came the way a message comes.

The subscriber waits for every publisher the directory named to it, connected or not yet: to know it has been told
of all of them, it asks the cache ``PING`` after its ``GET``s and waits for the ``PONG``, which comes after their
answers. Publishers announced later are probed when the subscriber connects to them; :attr:`DirectReach.reached`
lists every endpoint confirmed, in order (the lockstep's ack does not carry it yet: docs/wire.md says what that
leaves open). An endpoint withdrawn before it answered is not waited for; a stale one (its publisher died without
withdrawing) never answers, and holds the subscriber's readiness until its bounded wait ends.
"""

from __future__ import annotations

import itertools
import os

import zmq

from palpa.direct import REACH_PREFIX, directory_entry

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
        """Endpoint told of and not yet answered -> the first probe subscribed after its connection (0: it is not
        connected yet)."""
        self.reached: dict[str, None] = {}
        """The endpoints that answered, in order (a dict: an ordered set; live, it grows)."""

    def told(self, key: bytes, payload: bytes) -> None:
        """The directory told of (or withdrew) a direct publisher of a topic this node takes."""
        entry = directory_entry(key, payload)
        if entry is None:
            return
        endpoint, alive, _ = entry
        if not alive:
            self._needs.pop(endpoint, None)  # it will not answer: closed, what it sent is on its way
        elif endpoint not in self.reached:
            self._needs.setdefault(endpoint, 0)

    def connected(self, endpoint: str) -> None:
        """The subscriber socket just connected to ``endpoint``: probe it (and every other not yet answered)."""
        if endpoint in self.reached:
            return
        self._serial += 1
        key = self.prefix + str(self._serial).encode()
        self._sub.setsockopt(zmq.SUBSCRIBE, key)
        self._keys.append(key)
        self._needs[endpoint] = self._serial

    def unreachable(self, endpoint: str) -> None:
        """The socket did not connect to ``endpoint`` (palpa.direct logged why): not waited for, unless it is
        connected already (then its probe is out)."""
        if not self._needs.get(endpoint):
            self._needs.pop(endpoint, None)

    def answered(self, topic: bytes, endpoint: str) -> None:
        """A publisher's answer to probe ``topic``: ``endpoint`` has every subscription made before that probe."""
        try:
            serial = int(topic[len(self.prefix):])
        except ValueError:
            return
        need = self._needs.get(endpoint)
        if need is None or not 0 < need <= serial:
            return
        del self._needs[endpoint]
        self.reached[endpoint] = None
        if not any(self._needs.values()):  # no probe is waited for: stop receiving their answers
            for old in self._keys:
                self._sub.setsockopt(zmq.UNSUBSCRIBE, old)
            self._keys.clear()

    def pending(self) -> list[str]:
        """The endpoints told of that have not answered (connected or not)."""
        return list(self._needs)
