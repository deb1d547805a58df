"""Signed clock acknowledgements: what tells a launched node's acks from a client copying its header.

The bus authenticates no node name, and everything in an ack's header (name, incarnation, sequence number) is
visible to any subscriber, so binding acks to a header (palpa.timing.ackgate) stops clumsy and half-hearted
forgeries only. A launch therefore draws a secret for the run (its *master* key) and gives each node it starts
only that node's own key, ``HMAC(master, name)`` (``PALPA_CLOCK_KEY``); the clock entry gets the master
(``PALPA_CLOCK_MASTER_KEY``) and derives any node's key from its name. A node signs every ack: an HMAC-SHA256 over
its name, its incarnation, the ack's sequence number and the ack itself (``ClockAck.mac``). The clock believes an
ack about one of the launch's participants only with a valid signature: a client without the node's key can neither
make one up nor move a node's real ack to another sequence number (a replay of it is out of order), and no node can
sign for another. Keys travel in the environment only (readable by the same user, never on the bus).
"""

from __future__ import annotations

import hashlib
import hmac
import struct

import msgspec

from palpa.runtime_msgs import ClockAck

__all__ = ["MAC_BYTES", "node_key", "sign", "verify"]

MAC_BYTES = 16
"""Bytes of the signature kept (HMAC-SHA256 cut to 128 bits)."""
_IDS = struct.Struct(">QQ")
_encode = msgspec.msgpack.Encoder().encode


def node_key(master: bytes, node: str) -> bytes:
    """The key of node ``node`` under a launch's ``master`` key: it signs as that node and no other."""
    return hmac.new(master, b"palpa clock ack key\0" + node.encode(), hashlib.sha256).digest()


def sign(key: bytes, ack: ClockAck, inc: int, seq: int) -> bytes:
    """The signature of ``ack`` (its ``mac`` aside) sent as message ``seq`` of incarnation ``inc``."""
    unsigned = msgspec.structs.replace(ack, mac=b"") if ack.mac else ack
    body = ack.node.encode() + b"\0" + _IDS.pack(inc, seq) + _encode(unsigned)
    return hmac.new(key, body, hashlib.sha256).digest()[:MAC_BYTES]


def verify(key: bytes, ack: ClockAck, inc: int, seq: int) -> bool:
    """Whether ``ack``, received as message ``seq`` of incarnation ``inc``, carries the signature made with ``key``
    (its node's: :func:`node_key`)."""
    return len(ack.mac) == MAC_BYTES and hmac.compare_digest(ack.mac, sign(key, ack, inc, seq))
