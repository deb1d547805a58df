"""Heartbeats go on the wall clock, whatever clock a node runs on, and say how long the process has been up:
``palpa node list`` waits a wall-clock window, so a node on simulated time must still be heard in it."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from palpa.node.node import Node
from palpa.record.recorder import Recorder
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from palpa.testing import MemoryBus
from tests.procs import wait_until

pytestmark = pytest.mark.system  # heartbeats go on the wall clock by design: these wait for them in wall time


def _listen(bus: MemoryBus) -> tuple[Node, list[Heartbeat]]:
    beats: list[Heartbeat] = []
    watch = Node(name="watch", transport=bus.transport(), heartbeat_s=0)
    watch.subscribe(HEARTBEAT_TOPIC, Heartbeat, beats.append)
    return watch, beats


def test_sim_clock_node_beats_on_the_wall_clock_before_any_tick() -> None:
    bus = MemoryBus()
    watch, beats = _listen(bus)
    started = time.monotonic()  # before the node: its uptime starts inside the constructor, which can take a while
    node = Node(name="sim", transport=bus.transport(), sim_clock=True, wait_for_clock_s=0, heartbeat_s=0.05)

    def step() -> None:
        node.spin_once(0.01)
        watch.spin_once(0)

    wait_until(lambda: len(beats) >= 3, 5, "three heartbeats with no simulated time", step)
    assert node.clock.now_ns() == 0  # no tick ever came: the beats went on the wall clock
    assert 0 < beats[-1].uptime_s <= time.monotonic() - started
    node.close(0)
    watch.close(0)


def test_recorder_uptime_is_its_own_not_the_epoch(tmp_path: Path) -> None:
    bus = MemoryBus()
    watch, beats = _listen(bus)
    rec = Recorder(name="recorder", params={"output": str(tmp_path / "r.mcap")}, transport=bus.transport(),
                   heartbeat_s=0.05)

    def step() -> None:
        rec.spin_once(0.01)
        watch.spin_once(0)

    wait_until(lambda: any(b.node == "recorder" for b in beats), 5, "the recorder's heartbeat", step)
    assert 0 <= [b for b in beats if b.node == "recorder"][-1].uptime_s < 60
    rec.close(0)
    watch.close(0)
