"""models.timeseries: matching by time stamp. :meth:`StampedBuffer.at_each` (a driver's or an estimator's batch of
stamps in one call, issue 40) answers exactly what :meth:`StampedBuffer.at` answers for each stamp, and the buffer
that drops its old samples in blocks answers what one dropping them at every add answered."""

from __future__ import annotations

import random
from bisect import bisect_left
from collections.abc import Sequence

from models.timeseries import StampedBuffer


def _history(rng: random.Random) -> StampedBuffer:
    """Samples every ~2 ms with holes wider than ``max_gap_ns``, a few out of order and a few repeated stamps."""
    buf = StampedBuffer(horizon_ns=2_000_000_000, max_gap_ns=10_000_000)
    t = 1_000_000_000
    for _ in range(400):
        t += rng.choice((2_000_000, 2_000_000, 1_999_999, 15_000_000))
        buf.add(t, (rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(0, 90)))
        if rng.random() < 0.05:
            buf.add(t - rng.randrange(1, 3_000_000), (rng.random(), rng.random(), rng.random()))
        if rng.random() < 0.05:
            buf.add(t, (rng.random(), rng.random(), rng.random()))
    return buf


def test_at_each_answers_what_at_answers_for_every_stamp() -> None:
    rng = random.Random(7)
    for _ in range(20):
        buf = _history(rng)
        first, last = buf._t[0], buf._t[-1]  # noqa: SLF001 (the test reads the history it made)
        exact = rng.sample(buf._t, 30)  # noqa: SLF001
        stamps = sorted(rng.randrange(first - 20_000_000, last + 20_000_000) for _ in range(200)) + exact
        for order in (sorted(stamps), stamps, rng.sample(stamps, len(stamps))):  # in order, in runs, shuffled
            for hold in (0, 5_000_000):
                want = [buf.at(s, hold) for s in order]
                assert buf.at_each(order, hold) == want
                assert any(w is None for w in want) and any(w is not None for w in want)


def test_at_each_on_an_empty_history() -> None:
    assert StampedBuffer().at_each([1, 2, 3], 10) == [None, None, None]


class _DropEveryAdd:
    """The buffer as it was before it dropped old samples in blocks (issue 40): the reference it must match."""

    def __init__(self, horizon_ns: int, max_gap_ns: int) -> None:
        self.horizon_ns, self.max_gap_ns = horizon_ns, max_gap_ns
        self._t: list[int] = []
        self._v: list[tuple[float, ...]] = []

    def add(self, stamp_ns: int, values: Sequence[float]) -> None:
        v = tuple(map(float, values))
        if not self._t or stamp_ns > self._t[-1]:
            self._t.append(stamp_ns)
            self._v.append(v)
        else:
            i = bisect_left(self._t, stamp_ns)
            if i < len(self._t) and self._t[i] == stamp_ns:
                self._v[i] = v
            else:
                self._t.insert(i, stamp_ns)
                self._v.insert(i, v)
        cutoff = self._t[-1] - self.horizon_ns
        if self._t[0] < cutoff:
            k = bisect_left(self._t, cutoff)
            del self._t[:k]
            del self._v[:k]

    def at(self, stamp_ns: int, max_extrapolate_ns: int = 0) -> tuple[float, ...] | None:
        t = self._t
        if not t:
            return None
        i = bisect_left(t, stamp_ns)
        if i < len(t) and t[i] == stamp_ns:
            return self._v[i]
        if i == 0:
            return self._v[0] if t[0] - stamp_ns <= max_extrapolate_ns else None
        if i == len(t):
            return self._v[-1] if stamp_ns - t[-1] <= max_extrapolate_ns else None
        t0, t1 = t[i - 1], t[i]
        if t1 - t0 > self.max_gap_ns:
            return None
        w = (stamp_ns - t0) / (t1 - t0)
        return tuple([x + w * (y - x) for x, y in zip(self._v[i - 1], self._v[i], strict=True)])


def test_dropping_old_samples_in_blocks_answers_as_dropping_them_at_once() -> None:
    """Thousands of adds (in order, a little late, far older than the horizon, repeated stamps) with questions
    between them: the same answers, lengths and latest stamps as the buffer that dropped at every add."""
    rng = random.Random(11)
    buf, ref = StampedBuffer(horizon_ns=100_000_000, max_gap_ns=8_000_000), _DropEveryAdd(100_000_000, 8_000_000)
    t = 0
    for step in range(6000):
        t += rng.choice((2_000_000, 2_000_000, 3_000_000, 12_000_000))
        kind = rng.random()
        stamp = t if kind < 0.85 else t - rng.randrange(0, 30_000_000) if kind < 0.95 else \
            t - rng.randrange(100_000_000, 400_000_000)
        values = (rng.uniform(-5, 5), float(step))
        buf.add(stamp, values)
        ref.add(stamp, values)
        if step % 7 == 0:
            asks = [t - rng.randrange(-5_000_000, 150_000_000) for _ in range(12)]
            assert [buf.at(a, 3_000_000) for a in asks] == [ref.at(a, 3_000_000) for a in asks]
            assert buf.at_each(asks, 3_000_000) == [ref.at(a, 3_000_000) for a in asks]
            assert len(buf) == len(ref._t) and buf.latest_stamp == ref._t[-1]
    assert len(buf._t) > len(buf)  # noqa: SLF001 (some old samples are still waiting to be dropped)
