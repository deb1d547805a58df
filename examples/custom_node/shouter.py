"""An example of a custom palpa node that lives in its own file, outside the palpa source tree.

It listens to ``chatter`` (Text), and republishes every ``every``-th line in capitals, with ``suffix`` appended,
on ``shout``; the service ``shouter/reset`` starts its count again. See docs/custom-node.md for the walk-through; test_shouter.py tests it without a bus, and
launch.yaml runs it next to the demo talker::

    palpa launch examples/custom_node/launch.yaml

It can also run on its own against a running bus: ``python examples/custom_node/shouter.py -p suffix='!!'``.
"""

from __future__ import annotations

import palpa
from messages import Text, Trigger, TriggerResult


class Shouter(palpa.Node):
    """Text on ``chatter`` -> the same text in capitals plus ``suffix`` on ``shout``."""

    class Params(palpa.Params):
        suffix: str = "!"
        """Appended to every shouted line."""
        every: int = 1
        """Shout only every N-th line heard (1: all of them)."""

    params: Params  # typed: mypy checks every self.params.<name>

    def setup(self) -> None:
        if self.params.every < 1:
            raise palpa.ParamError(f"node {self.name!r}: parameter 'every' must be >= 1, got {self.params.every}")
        self.heard = 0
        self.out = self.publisher("shout", Text)
        self.subscribe("chatter", self.on_chatter)
        self.service("shouter/reset", Trigger, TriggerResult, self.on_reset)

    def on_reset(self, req: Trigger) -> TriggerResult:
        """Count lines from zero again (the next shout is after ``every`` more)."""
        heard, self.heard = self.heard, 0
        return TriggerResult(message=f"reset after {heard} lines", state="ok")

    def on_chatter(self, msg: Text) -> None:
        self.heard += 1
        if self.heard % self.params.every == 0:
            self.out.publish(Text(text=msg.text.upper() + self.params.suffix, stamp_ns=msg.stamp_ns))


if __name__ == "__main__":
    palpa.run_node(Shouter)
