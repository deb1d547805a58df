"""Multi-host, proven across Linux network namespaces (issue 22): the graph split over "hosts" on a bridge, over tcp
with CURVE, the CLI from a fourth host, and a link taken down mid-run and brought back.

Needs root and ``ip netns`` (iproute2); skipped with the reason otherwise. Every namespace is deleted at the end,
whatever happened (tests/netns.py). See docs/multihost.md for the same by hand.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from palpa.launch import load_launch
from palpa.launch.loader import parse_overrides
from palpa.net.keys import create_key_pair
from palpa.record.reader import iter_bag
from tests.netns import Hosts, why_no_netns
from tests.procs import REPO, Proc, ProcessGroup, wait_until

_WHY = why_no_netns()
pytestmark = [pytest.mark.system, pytest.mark.skipif(bool(_WHY), reason=_WHY or "ok")]
GEOMETRY = REPO / "phantoms" / "measured" / "airfloat_tumours.yaml"
HOST_OF = {"clock": 1, "pressure": 2, "fibre": 2, "estimator": 3, "map": 3, "scanner": 3}
"""Where each node of launch/scan_sim.yaml runs; the bus and the recorder are on host 1, the tools on host 4."""


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    h = Hosts(4)
    try:
        h.up()
        yield h
    finally:
        h.down()


class Graph:
    """A CURVE bus on host 1 and the environment every node and tool joins it with."""

    def __init__(self, hosts: Hosts, procs: ProcessGroup, tmp: Path, *latched: str) -> None:
        self.hosts, self.procs = hosts, procs
        keys, clients = tmp / "keys", tmp / "clients"
        clients.mkdir()
        create_key_pair(keys, "server")
        create_key_pair(keys, "node")
        (clients / "node.key").write_bytes((keys / "node.key").read_bytes())
        latch_args = [a for t in latched for a in ("--latched", t)]
        self.bus = procs.start(self.palpa(1, "bus", "--tcp", hosts.addr(1), "--curve-secret",
                                          str(keys / "server.key_secret"), "--curve-clients", str(clients),
                                          *latch_args))
        address = self.bus.wait_for_output("palpa bus ready", 15).split("ready ", 1)[1].strip()
        self.env = {**os.environ, "PALPA_BUS": address, "PALPA_BUS_SERVER_KEY": str(keys / "server.key"),
                    "PALPA_CURVE_SECRET": str(keys / "node.key_secret"), "PYTHONPATH": str(REPO)}

    def palpa(self, i: int, *args: str) -> list[str]:
        return self.hosts.cmd(i, sys.executable, "-m", "palpa.cli.main", *args)

    def start(self, i: int, *args: str, env: dict[str, str] | None = None) -> Proc:
        return self.procs.start(self.palpa(i, *args), env={**self.env, **(env or {})})

    def cli(self, *args: str, timeout: float = 30) -> str:
        """A palpa command from host 4, which runs nothing else."""
        out = subprocess.run(self.palpa(4, *args), env=self.env, capture_output=True, text=True, timeout=timeout)
        assert out.returncode == 0, out.stderr
        return out.stdout


def test_a_direct_topic_across_hosts_with_curve_survives_a_link_going_down(
        hosts: Hosts, procs: ProcessGroup, tmp_path: Path) -> None:
    """A talker on host 2 publishes ``chatter`` direct (its own CURVE socket on its own address, palpa.net.direct), a
    listener on host 3 and the recorder on host 1 connect to it there; host 2's link goes down and comes back."""
    g = Graph(hosts, procs, tmp_path, "calibration")
    rec_file = tmp_path / "run.mcap"
    recorder = g.start(1, "record", "-o", str(rec_file), "chatter", "calibration")
    talker = g.start(2, "run", "nodes.demo:Talker", "-p", "rate_hz=50", "--direct", "chatter")
    listener = g.start(3, "run", "nodes.demo:Listener")
    # a latched value published once from host 2, read later from host 4 (a late joiner)
    cal = g.start(2, "run", "nodes.demo:Talker", "--name", "cal", "-p", "count=1", "--remap", "chatter:=calibration")
    assert cal.wait(30) == 0, cal.output()
    listener.wait_for_output("heard 'hello", 30)
    assert "hello 1" in g.cli("topic", "echo", "calibration", "-n", "1", "--timeout", "20")
    wait_until(lambda: {"talker", "listener", "recorder"} <= set(g.cli("node", "list").split()), 30,
               "node list from host 4 to show the graph")
    assert re.search(r"pub chatter \[Text\] sent \d+ \(direct\)", g.cli("node", "list", "-v")), talker.output()
    assert "goes through the bus" not in talker.output()
    # host 2's link goes down for 3 s mid-run, then comes back: nothing hangs, the stream resumes
    hosts.link(2, "down")
    time.sleep(3.0)  # the outage itself (not a readiness wait)
    hosts.link(2, "up")
    before = listener.output().count("heard 'hello")
    wait_until(lambda: listener.output().count("heard 'hello") > before + 20, 60, "chatter to resume after the outage")
    assert "hello" in g.cli("topic", "echo", "chatter", "-n", "1", "--timeout", "20")
    for p in (talker, listener, recorder):
        assert p.popen.poll() is None, p.output()
    assert recorder.stop(20) == 0, recorder.output()
    assert g.bus.stop(10) == 0
    msgs = [m for m in iter_bag([rec_file]) if m.topic == "chatter"]
    assert len(msgs) > 50 and any(m.topic == "calibration" for m in iter_bag([rec_file]))


def _missing(report: str) -> int:
    """Messages a drop report counts missing: the recorder's last line (``topic: N missing`` each) or `bag info`'s
    drops line (``N messages missing``)."""
    return sum(int(n) for n in re.findall(r"(\d+) (?:messages )?missing", report))


def wait_for_listing(g: Graph, names: set[str], procs: list[Proc]) -> None:
    """Until `palpa node list` on host 4 shows every one of ``names`` (their heartbeats); on timeout, the last
    listing and the nodes' output."""
    listed: list[str] = []

    def all_listed() -> bool:
        listed.append(g.cli("node", "list"))
        return names <= set(listed[-1].split())

    try:
        wait_until(all_listed, 30, "node list from host 4 to show the graph")
    except AssertionError:
        raise AssertionError("\n".join([f"wanted {sorted(names)}, listed:", listed[-1] if listed else "",
                                        *(p.output()[-2000:] for p in procs)])) from None


def test_a_simulated_scan_split_over_three_hosts_survives_a_link_going_down(
        hosts: Hosts, procs: ProcessGroup, tmp_path: Path) -> None:
    """Bus, clock and recorder on host 1; the simulated probe drivers (pressure, fibre) on host 2; estimator, map
    and scanner on host 3; the tools on host 4. Host 2's link goes down during the raster: the lockstep clock
    holds simulated time for the nodes it cannot hear, so the scanner's watchdog (sim time) does not trip, and
    the scan finishes with a map once the link is back."""
    g = Graph(hosts, procs, tmp_path)
    rec_file, out_dir = tmp_path / "run.mcap", tmp_path / "map"
    recorder = g.start(1, "record", "-o", str(rec_file), "--exclude", "_palpa/clock.*")
    # launch/scan_sim.yaml's own nodes and parameters, resolved by the launch loader, each started on its host, under
    # the default (event) lockstep, its ticks and acks straight between hosts; a 2 x 2 touch-off: the outage is the
    # point here, not the touch-off
    plan = load_launch(REPO / "launch" / "scan_sim.yaml", parse_overrides([
        "region_mm:=[38.0, 12.0, 52.0, 24.0]", "spacing_mm:=4.0", "time_scale:=4.0",
        "touch_grid:=2", f"geometry:={GEOMETRY}", f"output_dir:={out_dir}"]), run_dir=tmp_path)
    placed = {spec.name: spec for spec in plan.nodes}
    assert set(placed) == set(HOST_OF), "scan_sim.yaml's nodes changed: place the new ones on a host"
    started: dict[str, Proc] = {}

    def start(name: str) -> Proc:
        spec = placed[name]
        # a dead clock stops a sim node after this many wall seconds: above the outage plus TCP's retransmit backoff
        env = {**g.env, **spec.env, **({"PALPA_SIM_CLOCK_TIMEOUT_S": "20"} if spec.env else {})}
        started[name] = procs.start(hosts.cmd(HOST_OF[name], *spec.argv()), env=env)
        return started[name]

    # everything but the scanner first, and host 4 sees all of them by their heartbeats (the scan, once started,
    # is too short to list it reliably on a loaded machine)
    for name in HOST_OF:
        if name != "scanner":
            start(name)
    clock, nodes = started["clock"], [started[n] for n in ("pressure", "fibre", "estimator", "map")]
    wait_for_listing(g, {*started, "recorder"}, [clock, *nodes])
    scanner = start("scanner")
    # the raster starts once the touch-off is done: take the drivers' host off the network during it
    scanner.wait_for_output("touch-off:", 90)
    assert scanner.popen.poll() is None, scanner.output()
    hosts.link(2, "down")
    down_ns = time.time_ns()
    time.sleep(2.0)  # the outage itself (not a readiness wait)
    up_ns = time.time_ns()
    hosts.link(2, "up")
    assert scanner.wait(90) == 0, scanner.output()
    assert "scan complete" in scanner.output()
    nodes[3].wait_for_output("map written", 30)
    # after the outage, from host 4: the nodes still running, by their heartbeats, and the scan plan the scanner
    # latched before it ended (a late joiner gets it from the bus's cache)
    wait_for_listing(g, {"clock", "pressure", "fibre", "estimator", "map", "recorder"}, [clock, *nodes])
    assert "waypoints" in g.cli("topic", "echo", "robot/plan", "-n", "1", "--timeout", "20")
    for p in [clock, *nodes]:
        assert p.popen.poll() is None, p.output()
        assert p.stop(20) == 0, p.output()
    assert recorder.stop(20) == 0, recorder.output()
    assert g.bus.stop(10) == 0
    # the recording survived the outage, and what the recorder counted lost is what the file shows lost
    topics = {m.topic for m in iter_bag([rec_file])}
    assert {"probe/heights", "pressure/state", "robot/pose", "stiffness/sample", "map/stiffness"} <= topics, topics
    # host 2's stream before the outage, none of it during (what was in flight may land in the first moments), and
    # after: the outage was real and mid-stream
    heard = np.array([m.log_time for m in iter_bag([rec_file]) if m.topic == "probe/heights"])
    during = ((heard > down_ns + 200_000_000) & (heard < up_ns)).sum()
    assert (heard < down_ns).any() and during == 0 and (heard > up_ns).any(), (during, down_ns, up_ns)
    report = recorder.output().strip().splitlines()[-1]
    info = g.cli("bag", "info", str(rec_file))
    drops = next(line for line in info.splitlines() if line.startswith("drops:"))
    assert _missing(report) == _missing(drops), (report, drops)
    grid = np.load(out_dir / "map.npz")
    # a cell counts from the map's min_count (3) samples on; below it the map leaves it NaN by design
    counted = grid["count"] >= 3
    assert counted.sum() > 0 and np.isfinite(grid["stiffness"][counted]).all()
