"""The launcher's own node on the bus (``_launch``): it hears the heartbeats (which tell the supervisor that the
recorder is ready), feeds the progress view and hands the simulation clock's ticks to the watch on a graph whose
time may stand still (palpa.launch.clockwatch). Split from palpa.launch.supervisor, which spins it in its loop."""

from __future__ import annotations

from typing import TYPE_CHECKING, TextIO

from palpa.launch.clockwatch import ClockWatch
from palpa.launch.output import Screen
from palpa.launch.progress import ProgressView, progress_fields
from palpa.net.address import BusAddress
from palpa.runtime_msgs import CLOCK_TOPIC, HEARTBEAT_TOPIC, ClockTick, Heartbeat

if TYPE_CHECKING:
    from palpa.node.node import Node, RawMessage

__all__ = ["Observer"]


class Observer:
    """What the launch hears on its bus: which nodes sent a heartbeat (:attr:`heard`), and the progress topic."""

    def __init__(self, screen: Screen, out: TextIO) -> None:
        self.heard: set[str] = set()
        """The names of the nodes whose heartbeat was heard so far."""
        self.node: Node | None = None
        """The observing node, once :meth:`start` made it."""
        self._screen = screen
        self._out = out

    def start(self, address: BusAddress | None, progress_topic: str | None, show: bool,
              clock_watch: ClockWatch | None) -> None:
        """Join the bus at ``address``: hear heartbeats, the clock's ticks for ``clock_watch``, and, when ``show``,
        show ``progress_topic`` in a progress view on the screen."""
        # here, not at the top: a launcher starts a composed simulation before it imports the node runtime
        from palpa.node.node import Node

        self.node = Node(name="_launch", bus=address, heartbeat_s=0)
        self.node.subscribe(HEARTBEAT_TOPIC, Heartbeat, self._on_heartbeat)
        if clock_watch is not None:
            self.node.subscribe(CLOCK_TOPIC, ClockTick, clock_watch.on_tick)
        if progress_topic and show:
            self._screen.view = ProgressView(progress_topic, self._out, terminal=self._out.isatty())
            self.node.subscribe_raw(progress_topic, self._on_progress)

    def _on_heartbeat(self, hb: Heartbeat) -> None:
        self.heard.add(hb.node)

    def _on_progress(self, raw: RawMessage) -> None:
        view = self._screen.view
        if view is None or raw.topic != view.topic:
            return
        fields = progress_fields(raw.payload)
        if fields is not None:
            view.update(fields, raw.recv_ns)
