"""Composition (issue 16): nodes in one process on a clock that jumps from event to event, in memory and behind
``palpa launch --in-process`` on a real bus."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from messages import Text
from nodes.demo import Listener, Talker
from palpa.errors import LaunchError
from palpa.launch import load_launch, parse_overrides
from palpa.launch.compose import compose_plan
from palpa.net.transport import Delivery
from palpa.node.node import Node
from palpa.record.reader import iter_bag, resolve_bag_paths
from palpa.timing.clock import MockClock
from palpa.timing.compose import Composition
from tests.procs import ProcessGroup
from tests.test_launch_smoke import REPO, Smoke, smoke

# around the r 5 x4 tumour at (45, 18); the measured geometry given as a user would (the in-memory composition
# below runs no prepare step). A coarse, fast raster after a 2 x 2 touch-off: two thirds of the simulated time of
# the defaults, and the touch-off's decisions on the probe's heights keep the comparison sensitive to the timeline
# (timers 1 ms late in the composition move the inclusion ~0.4 mm; without a touch-off, too little to see)
SMALL = ["region_mm:=[30.0, 6.0, 54.0, 30.0]", "spacing_mm:=4.0", "speed_mm_s:=40.0", "touch_grid:=2",
         f"geometry:={REPO / 'phantoms' / 'measured' / 'airfloat_tumours.yaml'}"]


def test_time_jumps_from_deadline_to_deadline_and_messages_arrive_at_once() -> None:
    """A 10 Hz talker for 1.05 s of simulated time: 11 ticks (at 0 and every 0.1 s), each heard by the listener at
    the tick's own time; the clock ends exactly where it was asked to stop, not at the next deadline."""
    clock = MockClock(0)
    comp = Composition(clock=clock, heartbeat_s=0)
    comp.add(Talker, "talker", {"rate_hz": 10.0})
    listener = comp.add(Listener, "listener")
    heard: list[tuple[int, int]] = []
    probe = comp.adopt(Node(name="probe", transport=comp.transport(), clock=clock, heartbeat_s=0))
    probe.subscribe("chatter", Text, lambda m: heard.append((m.stamp_ns, clock.now_ns())))
    comp.run(max_sim_s=1.05)
    assert listener.heard == 11
    assert [stamp for stamp, _ in heard] == [i * 100_000_000 for i in range(11)]
    assert all(stamp == at for stamp, at in heard)  # delivered before time moved on
    assert clock.now_ns() == 1_050_000_000


class _Quitter(Node):
    """Ends itself with exit code 3 after 0.25 s."""

    def setup(self) -> None:
        self.timer(0.25, lambda: self.request_shutdown(3), oneshot=True)


def test_nodes_that_end_are_closed_and_a_required_one_ends_the_composition_with_its_code() -> None:
    comp = Composition(clock=MockClock(0), heartbeat_s=0)
    comp.add(Talker, "talker", {"rate_hz": 100.0, "count": 5})
    comp.add(_Quitter, "quitter", required=True)
    listener = comp.add(Listener, "listener")
    assert comp.run(max_sim_s=60.0) == 3
    assert comp.ended == [("talker", 0), ("quitter", 3)]
    assert comp.clock.now_ns() == 250_000_000  # not the minute asked for
    assert listener.heard == 5 and comp.nodes == []


class _FailsOnStop(Node):
    """Reports, as it is stopped, that its work failed (as a map holding part of a scan does)."""

    def setup(self) -> None:
        self.timer(0.1, lambda: None)

    def on_shutdown(self) -> None:
        self.exit_code = 1


def test_a_node_that_reports_failure_as_it_stops_fails_the_composition() -> None:
    """Stopped (Ctrl-C, or the required node's clean end), a node that reports failure as it closes makes the
    composition end non-zero, as its process of its own would have failed the launch."""
    comp = Composition(clock=MockClock(0), heartbeat_s=0)
    comp.add(_FailsOnStop, "map")
    comp.add(Talker, "talker", {"rate_hz": 10.0})
    assert comp.run(max_sim_s=0.5) == 1
    comp = Composition(clock=MockClock(0), heartbeat_s=0)
    comp.add(Talker, "talker", {"rate_hz": 10.0})
    assert comp.run(max_sim_s=0.5) == 0


def test_compose_plan_folds_sim_nodes_clock_and_recorder_into_one_entry(tmp_path: Path) -> None:
    plan = compose_plan(load_launch(REPO / "launch" / "scan_sim.yaml", {}, run_dir=tmp_path))
    assert [n.name for n in plan.nodes] == ["sim"]
    entry = plan.nodes[0]
    assert entry.required and plan.record is None and entry.cmd is not None
    graph = json.loads(entry.cmd[-1])
    assert [n["name"] for n in graph["nodes"]] == ["recorder", "pressure", "fibre", "estimator", "map", "scanner"]
    assert "PALPA_SIM_CLOCK" not in entry.env


def test_compose_plan_refuses_a_file_without_sim_clock_nodes(tmp_path: Path) -> None:
    with pytest.raises(LaunchError, match="no node runs on the simulated clock"):
        compose_plan(load_launch(REPO / "launch" / "talker_listener.yaml", {}, run_dir=tmp_path))


def _scan(tmp: Path) -> tuple[list[dict[str, float]], np.ndarray]:
    """The air-float scan of a small region, composed in memory (no bus)."""
    from palpa.targets import load_node_class

    plan = compose_plan(load_launch(REPO / "launch" / "scan_sim.yaml", parse_overrides(SMALL), run_dir=tmp))
    comp = Composition(clock=MockClock(1_700_000_000_000_000_000), heartbeat_s=0)
    for n in json.loads(plan.nodes[0].cmd[-1])["nodes"]:  # type: ignore[index]
        if n["name"] != "recorder":
            comp.add(load_node_class(n["target"]), n["name"], n["params"], required=n["required"])
    assert comp.run(max_sim_s=120.0) == 0
    out = tmp / "map"
    return json.loads((out / "inclusions.json").read_text()), np.load(out / "map.npz")["stiffness"]


@pytest.mark.system
def test_the_same_seed_gives_the_same_map(tmp_path: Path) -> None:
    a, grid_a = _scan(tmp_path / "a")
    b, grid_b = _scan(tmp_path / "b")
    assert a and a == b
    assert np.array_equal(grid_a, grid_b, equal_nan=True)


@pytest.mark.system
def test_in_process_launch_is_seen_on_the_bus_by_outside_tools(procs: ProcessGroup, tmp_path: Path) -> None:
    """`palpa launch scan_sim.yaml --in-process`: a node of our own on the run's bus hears the composed graph's
    topics and heartbeats (what topic echo/hz and node list use); the scan ends by itself with exit 0, or, stopped
    before its end, with 1 (its map holds part of it)."""
    smoke(REPO / "launch" / "scan_sim.yaml",
          Smoke(args=["region_mm:=[20.0, 20.0, 30.0, 30.0]", "spacing_mm:=5.0"],
                topics=["robot/pose", "probe/heights", "stiffness/sample", "map/inclusions", "_palpa/heartbeat"],
                timeout=60, scan=True),
          procs, tmp_path, ["--in-process"])
    assert (tmp_path / "run" / "recording.mcap").stat().st_size > 10_000


@pytest.mark.timeout(400)
@pytest.mark.system
def test_in_process_and_multi_process_find_the_same_inclusions(procs: ProcessGroup, tmp_path: Path) -> None:
    """The same small scan composed and as one process per node: the same inclusions, within 0.05 mm (the event
    lockstep gives the processes the composition's timeline: same timer instants, every message handled at the
    instant it was sent). The composed side runs in memory (what `palpa launch --in-process` runs, without the
    bus and the recorder, which change no timeline): test_in_process_launch_is_seen_on_the_bus_by_outside_tools
    covers the launch."""
    from tests.test_scan_e2e import inclusions, run_launch

    a, _ = _scan(tmp_path / "in")
    run_launch(procs, tmp_path / "multi", "launch/scan_sim.yaml", *SMALL, "time_scale:=5.0", timeout=300)
    b = inclusions(tmp_path / "multi")
    # a node starved of CPU for the clock's participant timeout stops holding simulated time back, and a message
    # lost for that long stops being waited for: either breaks the lockstep, and the clock's warning says which
    warnings = [line for log in (tmp_path / "multi").glob("*.log") for line in log.read_text().splitlines()
                if "WARNING" in line]
    assert len(a) == len(b) >= 1, (a, b, warnings)
    for x in a:
        gap = min(math.dist((x["x_mm"], x["y_mm"]), (y["x_mm"], y["y_mm"])) for y in b)
        assert gap <= 0.05, (gap, a, b, warnings)
    # launch/scan_sim.yaml as processes: its smoke (tests/test_launch_smoke.py) is this run, every topic it should
    # carry in the recording
    recorded = {m.topic for m in iter_bag(resolve_bag_paths(str(tmp_path / "multi" / "recording.mcap")))}
    smoke_topics = {"robot/pose", "robot/plan", "robot/scan_status", "probe/heights", "pressure/state",
                    "stiffness/sample", "map/stiffness", "map/inclusions"}
    assert smoke_topics <= recorded, sorted(smoke_topics - recorded)


class _LateEchoBus:
    """The composition's bridge to the real bus, reduced to what matters here: the proxy hands back to the bridge's
    subscriptions everything the composition sent, but only when :meth:`release` says (a proxy slowed by load)."""

    def __init__(self) -> None:
        self.subscribed: set[bytes] = set()
        self.outside: set[bytes] = set()
        """What subscribers elsewhere on the bus take (the bridge's own subscriptions reach its publisher too)."""
        self.held: list[list[bytes]] = []
        self.back: list[Delivery] = []

    def subscribe(self, topic: bytes, request_latched: bool) -> None:
        self.subscribed.add(topic)

    def unsubscribe(self, topic: bytes) -> None:
        self.subscribed.discard(topic)

    def send(self, frames: list[bytes], latched: bool) -> None:
        self.held.append(list(frames))

    def has_subscribers(self, topic: bytes) -> bool:
        return any(topic.startswith(t) for t in self.subscribed | self.outside)

    def release(self) -> None:
        self.back += [Delivery(f, False) for f in self.held if any(f[0].startswith(t) for t in self.subscribed)]
        self.held = []

    def poll(self, timeout_s: float) -> list[Delivery]:
        back, self.back = self.back, []
        return back

    def close(self, linger_ms: int) -> None:
        pass


def test_a_service_call_echoed_back_late_through_the_bridge_is_not_run_again() -> None:
    """A request a composed client sent comes back from the real bus's proxy after the client's next call: the
    composition knows it for its own (the header names the client, ``<node>.<id>``) and drops it; the server never
    sees it (and, at most once, would not run it again if it did)."""
    from tests.test_service import Adder, AddReply, AddRequest

    bridge = _LateEchoBus()
    comp = Composition(bridge=bridge, clock=MockClock(0), heartbeat_s=0)  # type: ignore[arg-type]
    server = comp.add(Adder, "math")
    caller = comp.adopt(Node(name="caller", transport=comp.transport(), clock=comp.clock, heartbeat_s=0))
    add = caller.client("math/add", AddRequest, AddReply)
    comp.settle()
    first = add.call_async(AddRequest(a=1.0, b=1.0))
    comp.settle()
    second = add.call_async(AddRequest(a=2.0, b=2.0))
    comp.settle()
    assert first.result().total == 2.0 and second.result().total == 4.0
    assert b"math/add/request" in bridge.subscribed   # a service's requests may come from outside too
    assert [f[0] for f in bridge.held].count(b"math/add/request") == 2  # out on the bus, to come back
    bridge.release()    # both requests (and replies) come back now, the first after the second was served
    comp._wait_outside(0.0)
    comp.settle()
    assert server.srv.calls == 2 and server.srv.repeats == 0
    comp.close()


def test_the_bridge_carries_out_what_the_bus_listens_to_and_every_latched_value() -> None:
    """A topic nobody on the real bus takes stays in the composition (a PUB socket would drop it after its cost to
    the composition); one taken there goes out, and a latched value goes to the bus's cache whoever listens."""
    from messages import Text

    bridge = _LateEchoBus()
    bridge.outside.add(b"seen/")
    comp = Composition(bridge=bridge, clock=MockClock(0), heartbeat_s=0)  # type: ignore[arg-type]
    node = comp.adopt(Node(name="talker", transport=comp.transport(), clock=comp.clock, heartbeat_s=0))
    for topic, latched in (("seen/x", False), ("unseen/x", False), ("state/x", True)):
        node.publisher(topic, Text, latched=latched).publish(Text(text=topic))
    comp.settle()
    assert sorted(f[0] for f in bridge.held) == [b"seen/x", b"state/x"]
    comp.close()
