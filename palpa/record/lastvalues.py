"""The last value of every latched channel the recorder has seen, which opens each split piece (so a piece stands
alone), bounded in bytes: past the bound the least recently updated values are forgotten, and the caller is told
which, to log and count them."""

from __future__ import annotations

from collections.abc import Hashable, ItemsView, Iterator
from typing import Generic, TypeVar

from palpa.node.endpoints import RawMessage

__all__ = ["LastValues"]

K = TypeVar("K", bound=Hashable)


def _size(raw: RawMessage) -> int:
    return len(raw.payload) + sum(len(b) for b in raw.blobs)


class LastValues(Generic[K]):
    """Key -> last RawMessage, at most ``max_bytes`` of payload and blobs together."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._values: dict[K, RawMessage] = {}  # least recently updated first
        self.bytes = 0

    def put(self, key: K, raw: RawMessage) -> list[K]:
        """Keep ``raw`` as ``key``'s last value; returns the keys forgotten to make room (``key`` itself when
        ``raw`` alone is over the bound: then nothing is kept for it)."""
        size = _size(raw)
        old = self._values.pop(key, None)
        if old is not None:
            self.bytes -= _size(old)
        if size > self.max_bytes:
            return [key]
        forgotten = []
        while self.bytes + size > self.max_bytes:
            gone = next(iter(self._values))
            self.bytes -= _size(self._values.pop(gone))
            forgotten.append(gone)
        self._values[key] = raw
        self.bytes += size
        return forgotten

    def items(self) -> ItemsView[K, RawMessage]:
        return self._values.items()

    def __len__(self) -> int:
        return len(self._values)

    def __iter__(self) -> Iterator[K]:
        return iter(self._values)
