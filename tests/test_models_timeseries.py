"""models.timeseries: matching by time stamp. :meth:`StampedBuffer.at_each` (a driver's or an estimator's batch of
stamps in one call, issue 40) answers exactly what :meth:`StampedBuffer.at` answers for each stamp."""

from __future__ import annotations

import random

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
