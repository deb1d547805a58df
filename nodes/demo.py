"""The smallest real graph: a talker and a listener (used by the runtime tests and the docs)."""

from __future__ import annotations

import palpa
from messages import Text


class Talker(palpa.Node):
    """Publishes ``Text`` on ``chatter`` at ``rate_hz``; stops by itself after ``count`` messages if set."""

    class Params(palpa.Params):
        rate_hz: palpa.RunTime[palpa.Positive] = 10.0
        """Applied at once when changed at run time (on_params_changed re-times the timer)."""
        text: palpa.RunTime[str] = "hello"
        count: palpa.RunTime[int] = 0
        """Stop (exit 0) after this many messages; 0 runs until stopped. Text and count are read at every tick."""

    params: Params  # typed: mypy checks every self.params.<name>

    def setup(self) -> None:
        if self.params.rate_hz <= 0:
            raise palpa.ParamError(f"{self.name}: rate_hz must be > 0, got {self.params.rate_hz}")
        self.out = self.publisher("chatter", Text)
        self.ticker = self.timer(1.0 / self.params.rate_hz, self.tick, first_in_s=0.0)

    def on_params_changed(self, old: Talker.Params, new: Talker.Params) -> bool | None:
        """A new ``rate_hz`` takes effect at once (``palpa param set talker rate_hz 20``)."""
        if new.rate_hz <= 0:
            raise palpa.ParamError(f"parameter 'rate_hz': must be > 0, got {new.rate_hz}")
        if new.rate_hz != old.rate_hz:
            self.ticker.cancel()
            self.ticker = self.timer(1.0 / new.rate_hz, self.tick, first_in_s=0.0)
        return None

    def tick(self) -> None:
        seq = self.out.publish(Text(text=f"{self.params.text} {self.out.seq + 1}", stamp_ns=self.clock.now_ns()))
        if self.params.count and seq >= self.params.count:
            self.request_shutdown(0)

    def on_shutdown(self) -> None:
        self.log.info("sent %d", self.out.seq)


class Listener(palpa.Node):
    """Logs every ``Text`` heard on ``chatter`` and republishes its length on ``chatter_len``; stops by itself after
    ``count`` messages if set."""

    class Params(palpa.Params):
        count: int = 0
        """Stop (exit 0) after hearing this many messages; 0 runs until stopped."""

    params: Params

    def setup(self) -> None:
        self.heard = 0
        self.out = self.publisher("chatter_len", Text)
        self.subscribe("chatter", self.on_text)

    def on_text(self, msg: Text) -> None:
        self.heard += 1
        self.log.info("heard %r", msg.text)
        self.out.publish(Text(text=str(len(msg.text)), stamp_ns=msg.stamp_ns))
        if self.params.count and self.heard >= self.params.count:
            self.request_shutdown(0)


def talker_main() -> None:
    palpa.run_node(Talker)


if __name__ == "__main__":
    talker_main()
