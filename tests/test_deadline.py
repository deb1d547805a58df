"""Waits and deadlines read the node's clock (palpa.timing.clock.Deadline): simulated time on a simulated clock, so a
busy machine cannot make them fire early; the monotonic clock behind a wall clock, so a wall-clock step cannot; and
on a clock that stands still while its executor blocks, a bounded number of rounds instead of a hang."""

from __future__ import annotations

import time

import pytest

import palpa
from palpa.node.service import Responder, ServiceTimeout
from palpa.testing import GraphHarness
from palpa.timing.clock import FROZEN_ROUNDS, Deadline, MockClock, SystemClock, TopicClock


class Ask(palpa.Message, frozen=True, kw_only=True):
    n: int


class Answer(palpa.Message, frozen=True, kw_only=True):
    n: int


class Silent(palpa.Node):
    """Serves ``ask`` and never answers (every request is deferred and dropped)."""

    def setup(self) -> None:
        self.srv = self.service("ask", Ask, Answer, self.on_ask)

    def on_ask(self, req: Ask) -> Responder[Answer]:
        return self.srv.defer()


def _wall_jumps(monkeypatch: pytest.MonkeyPatch, seconds: float) -> None:
    """From now on the wall clocks read ``seconds`` later: what a starved process sees when it next runs."""
    mono, mono_ns, wall_ns = time.monotonic, time.monotonic_ns, time.time_ns
    monkeypatch.setattr(time, "monotonic", lambda: mono() + seconds)
    monkeypatch.setattr(time, "monotonic_ns", lambda: mono_ns() + int(seconds * 1e9))
    monkeypatch.setattr(time, "time_ns", lambda: wall_ns() + int(seconds * 1e9))


def test_a_deadline_on_a_simulated_clock_passes_with_simulated_time(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = MockClock()
    deadline = Deadline(clock, 1.0)
    _wall_jumps(monkeypatch, 3600.0)
    clock.advance(0.999)
    assert not deadline.passed()
    clock.advance(0.002)
    assert deadline.passed() and deadline.remaining_s() == 0.0


def test_a_deadline_on_the_wall_clock_is_measured_on_the_monotonic_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """An NTP step of the wall clock neither fires nor stretches a limit (as with time.monotonic before)."""
    deadline = Deadline(SystemClock(), 10.0)
    monkeypatch.setattr(time, "time_ns", lambda: 0)  # the wall clock stepped back to 1970
    assert not deadline.passed() and 0.0 < deadline.remaining_s() <= 10.0
    _wall_jumps(monkeypatch, 11.0)
    assert deadline.passed()


def test_a_deadline_on_a_clock_that_stands_still_passes_after_frozen_rounds() -> None:
    """A node blocked in a wait is its executor's thread: a mock clock cannot move until the wait ends, so the
    wait ends after FROZEN_ROUNDS checks without time moving; a move of the clock starts the count again, and a
    wait without a limit stays one."""
    clock = MockClock()
    deadline = Deadline(clock, 5.0)
    assert not any(deadline.passed() for _ in range(FROZEN_ROUNDS - 1))
    clock.advance(0.001)
    assert [deadline.passed() for _ in range(FROZEN_ROUNDS + 1)] == [False] * FROZEN_ROUNDS + [True]
    unlimited = Deadline(clock, None)
    assert not any(unlimited.passed() for _ in range(2 * FROZEN_ROUNDS))


def test_a_deadline_on_a_topic_clock_that_stops_passes_after_frozen_rounds() -> None:
    """A sim-clock node's clock can stop while it waits (a lockstep clock holding time for it, a paused replay):
    then too the wait ends after FROZEN_ROUNDS checks, and a tick in between starts the count again."""
    clock = TopicClock()
    clock.update(1_000_000_000)
    deadline = Deadline(clock, 5.0)
    assert deadline.remaining_s() == pytest.approx(5.0)  # this clock moves by itself: there is time to wait for
    assert not any(deadline.passed() for _ in range(FROZEN_ROUNDS - 1))
    clock.update(1_001_000_000)
    assert [deadline.passed() for _ in range(FROZEN_ROUNDS + 1)] == [False] * FROZEN_ROUNDS + [True]


def test_an_async_call_expires_on_simulated_time_not_on_a_busy_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    with GraphHarness([(Silent, None)]) as g:
        caller = g.add(palpa.Node, name="caller")
        ask = caller.client("ask", Ask, Answer, timeout_s=1.0)
        assert ask.wait_for_service(1.0)
        fut = ask.call_async(Ask(n=1))
        g.advance(0.5)
        _wall_jumps(monkeypatch, 60.0)  # the process was starved for a minute of wall time
        g.advance(0.4)
        assert not fut.done()
        g.advance(0.2)
        assert fut.done() and isinstance(fut.exception(), ServiceTimeout)


def test_a_blocking_call_on_a_mock_clock_times_out_instead_of_hanging() -> None:
    """The harness's clock cannot move while the caller blocks: once the graph has had its rounds without an
    answer, none can come before time moves, and the call ends as its deadline would."""
    with GraphHarness([(Silent, None)]) as g:
        caller = g.add(palpa.Node, name="caller")
        ask = caller.client("ask", Ask, Answer, timeout_s=30.0)
        assert ask.wait_for_service(1.0)
        start = g.clock.now_ns()
        with pytest.raises(ServiceTimeout):
            ask.call(Ask(n=1))
        assert g.clock.now_ns() == start
        sub = caller.subscribe("nothing/here", Ask)
        assert sub.next(timeout_s=30.0) is None


def test_a_blocking_wait_on_a_still_clock_ends_its_own_call_only() -> None:
    """The frozen-clock rule belongs to the waiter: a blocking call's rounds on a clock that stands still end that
    call, not another call sent before it whose deadline has not come (it was ended by the other wait's round count,
    "no reply within the deadline", at the same simulated instant it was sent)."""
    with GraphHarness([(Silent, None)]) as g:
        caller = g.add(palpa.Node, name="caller")
        ask = caller.client("ask", Ask, Answer, timeout_s=30.0)
        assert ask.wait_for_service(1.0)
        earlier = ask.call_async(Ask(n=1))
        with pytest.raises(ServiceTimeout):
            ask.call(Ask(n=2))
        assert not earlier.done()  # its 30 s of simulated time have not passed
        g.advance(31.0)
        assert earlier.done() and isinstance(earlier.exception(), ServiceTimeout)
