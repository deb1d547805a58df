"""One in-process executor (issue 38): the test harness and ``palpa launch FILE --in-process`` run the same
timeline on the demo graph, message for message.

The launch runs as a process on a real bus and records (its recorder is composed first, so it hears every
message in the order the composition handles them); the harness composes the same file's nodes with
:meth:`GraphHarness.from_launch` in this process, its probe hearing everything first the same way. Both sides
are then the sequence of (simulated ns since the start, topic, publisher, seq) of every message the graph's nodes
published, the runtime's own topics (heartbeats, logs, service announcements: ``_palpa/``) aside.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from palpa.launch import parse_overrides
from palpa.record.reader import iter_bag
from palpa.testing import GraphHarness
from tests.procs import ProcessGroup
from tests.test_compose import SMALL
from tests.test_scan_e2e import run_launch

pytestmark = pytest.mark.system

SCAN = "launch/scan_sim.yaml"
Event = tuple[int, str, str, int]


def _ours(topic: str) -> bool:
    return not topic.startswith("_palpa/")


def _launch_timeline(bag: Path, names: set[str]) -> list[Event]:
    msgs = [m for m in iter_bag([bag]) if m.node in names and _ours(m.topic)]
    start = min(m.publish_time for m in msgs)
    return [(m.publish_time - start, m.topic, m.node, m.seq) for m in msgs]


def _harness_timeline(g: GraphHarness, start: int) -> list[Event]:
    return [(r.header.stamp - start, r.topic, r.header.node, r.header.seq) for r in g.raw
            if r.header.node != "harness" and _ours(r.topic)]


@pytest.mark.timeout(120)
def test_the_harness_runs_the_timeline_of_an_in_process_launch(procs: ProcessGroup, tmp_path: Path) -> None:
    """The whole small scan, up to the instant the scanner (the required node) ends it: touch-off, raster, the
    map's inclusions."""
    run_launch(procs, tmp_path / "launch", SCAN, "--in-process", *SMALL, timeout=90)
    with GraphHarness.from_launch(SCAN, run_dir=tmp_path / "harness", **parse_overrides(SMALL)) as g:
        names = {n.name for n in g.nodes}
        theirs = _launch_timeline(tmp_path / "launch" / "recording.mcap", names)
        end = max(e[0] for e in theirs if e[2] == "scanner")
        start = g.clock.now_ns()
        g.advance(end / 1e9)
        ours = _harness_timeline(g, start)
    assert end > 10e9
    assert {e[1] for e in ours} >= {"robot/pose", "probe/heights", "stiffness/sample", "robot/scan_status"}
    assert len(ours) > 10_000
    first = next((i for i, (a, b) in enumerate(zip(ours, theirs, strict=False)) if a != b), None)
    at = min(len(ours), len(theirs)) if first is None else first
    assert first is None and len(ours) == len(theirs), (
        f"timelines part at event {at}: harness {ours[max(at - 3, 0):at + 3]}, launch {theirs[max(at - 3, 0):at + 3]}"
        f" ({len(ours)} vs {len(theirs)} events)")
