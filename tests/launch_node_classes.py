"""Palpa node classes for the launch tests (imported through a launch file's python_path)."""

from __future__ import annotations

import palpa
from messages import Text


class LaunchTestProgress(palpa.Message, frozen=True, kw_only=True):
    """A stand-in for a scan status: only the field names matter to the launcher."""

    progress: float
    state: str = ""
    line: int = 0
    lines: int = 0


class ProgressTicker(palpa.Node):
    """Publishes progress from 0 to 1 in ``steps`` steps every ``period_s``, warns once halfway, then exits 0."""

    class Params(palpa.Params):
        steps: int = 10
        period_s: float = 0.1
        topic: str = "test/status"

    def setup(self) -> None:
        self.step = 0
        self.out = self.publisher(self.params.topic, LaunchTestProgress)
        self.timer(self.params.period_s, self.tick)

    def tick(self) -> None:
        self.step += 1
        n = self.params.steps
        self.out.publish(LaunchTestProgress(progress=self.step / n, state="scanning", line=self.step, lines=n))
        self.log.info("step %d of %d", self.step, n)
        if self.step == n // 2:
            self.log.warning("halfway there")
        if self.step >= n:
            self.request_shutdown(0)


class Burst(palpa.Node):
    """Once someone listens, publishes ``n`` texts of ``size`` bytes at once on ``test/burst``, then exits 0: most of
    the burst is still queued when the node closes."""

    class Params(palpa.Params):
        n: int = 300
        size: int = 20_000

    params: Params

    def setup(self) -> None:
        self.out = self.publisher("test/burst", Text)
        self.timer(0.01, self.tick)

    def tick(self) -> None:
        if not self.out.has_subscribers:
            return
        for i in range(self.params.n):
            self.out.publish(Text(text=f"{i} " + "x" * self.params.size))
        self.request_shutdown(0)


class Freezer(palpa.Node):
    """On the simulated clock: a 10 ms timer, and after ``after_s`` simulated seconds a callback that holds the node
    for ``hold_s`` wall seconds (or until it is asked to stop): a node stuck but alive, which the lockstep clock
    waits for, so the graph's time stands still."""

    class Params(palpa.Params):
        after_s: float = 0.5
        hold_s: float = 60.0

    def setup(self) -> None:
        self.timer(0.01, lambda: None)
        self.timer(self.params.after_s, self.freeze, oneshot=True)

    def freeze(self) -> None:
        import time

        self.log.warning("freezing for %g s (wall clock)", self.params.hold_s)
        deadline = time.monotonic() + self.params.hold_s
        while time.monotonic() < deadline and not self.is_shutdown:
            time.sleep(0.05)


class NeedsFile(palpa.Node):
    """Reads ``path`` as it is built (a file a launch's prepare step writes), says what it read, then exits 0: built
    before the prepare step has run, it fails."""

    class Params(palpa.Params):
        path: str = ""

    params: Params

    def setup(self) -> None:
        with open(self.params.path, encoding="utf-8") as f:
            self.log.info("read: %s", f.read().strip())
        self.timer(0.01, lambda: self.request_shutdown(0), oneshot=True)
