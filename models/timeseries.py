"""Matching measurements by time stamp, never by arrival order.

:class:`StampedBuffer` keeps the recent history of one signal (a pose, a pressure) and answers "what was it at
time t?" by linear interpolation between the samples around t. A question about a time outside the history,
or inside a hole wider than ``max_gap_ns``, gets None: the caller marks its sample invalid (stale data).
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Sequence

__all__ = ["StampedBuffer"]

_DROP_BLOCK = 256
"""Samples out of the horizon kept in the lists (unread) until this many can be dropped at once."""


class StampedBuffer:
    """A time-ordered history of vector samples with interpolation at arbitrary stamps (ns)."""

    def __init__(self, horizon_ns: int = 2_000_000_000, max_gap_ns: int = 100_000_000) -> None:
        if horizon_ns <= 0 or max_gap_ns <= 0:
            raise ValueError("horizon_ns and max_gap_ns must be > 0")
        self.horizon_ns = horizon_ns
        self.max_gap_ns = max_gap_ns
        self._t: list[int] = []
        self._v: list[tuple[float, ...]] = []
        self._start = 0
        """The history is ``_t[_start:]``: what fell out of the horizon before it is dropped from the lists in
        blocks of :data:`_DROP_BLOCK` (one list shift per sample cost as much as the rest of :meth:`add`)."""

    def __len__(self) -> int:
        return len(self._t) - self._start

    @property
    def latest_stamp(self) -> int | None:
        return self._t[-1] if self._t else None

    def add(self, stamp_ns: int, values: Sequence[float]) -> None:
        """Append a sample; one older than the newest is inserted in order; a repeated stamp replaces."""
        v = tuple(map(float, values))
        t, start = self._t, self._start
        if not t or stamp_ns > t[-1]:
            t.append(stamp_ns)
            self._v.append(v)
        else:
            i = bisect_left(t, stamp_ns, start)
            if i < len(t) and t[i] == stamp_ns:
                self._v[i] = v
            else:  # (at _start when older than the whole history: the order before _start no longer matters)
                t.insert(i, stamp_ns)
                self._v.insert(i, v)
        cutoff = t[-1] - self.horizon_ns
        if t[start] < cutoff:
            start = self._start = bisect_left(t, cutoff, start)
            if start >= _DROP_BLOCK:
                del t[:start]
                del self._v[:start]
                self._start = 0

    def at(self, stamp_ns: int, max_extrapolate_ns: int = 0) -> tuple[float, ...] | None:
        """The value at ``stamp_ns``: interpolated between neighbours no further apart than ``max_gap_ns``;
        held from the nearest end sample if ``stamp_ns`` is within ``max_extrapolate_ns`` of it; else None."""
        t, start = self._t, self._start
        if not t:
            return None
        i = bisect_left(t, stamp_ns, start)
        if i < len(t) and t[i] == stamp_ns:
            return self._v[i]
        if i == start:
            return self._v[start] if t[start] - stamp_ns <= max_extrapolate_ns else None
        if i == len(t):
            return self._v[-1] if stamp_ns - t[-1] <= max_extrapolate_ns else None
        t0, t1 = t[i - 1], t[i]
        if t1 - t0 > self.max_gap_ns:
            return None
        w = (stamp_ns - t0) / (t1 - t0)
        a, b = self._v[i - 1], self._v[i]
        return tuple([x + w * (y - x) for x, y in zip(a, b, strict=True)])  # a list first: faster than a generator

    def at_each(self, stamps: Sequence[int], max_extrapolate_ns: int = 0) -> list[tuple[float, ...] | None]:
        """:meth:`at` of every stamp, in one call: the same values to the bit, without a call and a binary search
        over the whole history per stamp (a driver asks for 50 stamps at a time, mostly in order: each search starts
        where the previous stamp's ended, when that stamp was earlier)."""
        t, v, gap, start = self._t, self._v, self.max_gap_ns, self._start
        n = len(t)
        if not n:
            return [None] * len(stamps)
        out: list[tuple[float, ...] | None] = []
        i, prev = start, t[start]
        for stamp in stamps:
            i = bisect_left(t, stamp, i if stamp >= prev else start)
            prev = stamp
            if i < n and t[i] == stamp:
                out.append(v[i])
            elif i == start:
                out.append(v[start] if t[start] - stamp <= max_extrapolate_ns else None)
            elif i == n:
                out.append(v[-1] if stamp - t[-1] <= max_extrapolate_ns else None)
            else:
                t0, t1 = t[i - 1], t[i]
                if t1 - t0 > gap:
                    out.append(None)
                else:
                    w = (stamp - t0) / (t1 - t0)
                    out.append(tuple([x + w * (y - x) for x, y in zip(v[i - 1], v[i], strict=True)]))
        return out
