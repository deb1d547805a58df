"""The Foxglove bridge (palpa viz) spoken to by a WebSocket client: schemas, JSON payloads, latched values for a
late subscriber, drops counted instead of waited for, abrupt disconnects, client publishing, loopback only."""

from __future__ import annotations

import json
import math
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import foxglove
import msgspec
import pytest

import messages  # noqa: F401
import palpa
from messages import EStop, Inclusions, ProbeHeights, RobotPose, ScanPlan, StiffnessMap
from messages.robot import PlanWaypoint
from nodes.mapping.foxglove_views import ScanViews
from palpa.errors import ParamError
from palpa.net.address import BusAddress
from palpa.testing import GraphHarness
from palpa.viz import SUBPROTOCOL, Bridge
from tests.foxglove_client import FoxgloveClient
from tests.procs import ProcessGroup, palpa_cmd, wait_until
from tests.test_launch_smoke import REPO

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


@pytest.fixture
def graph() -> Iterator[tuple[GraphHarness, Bridge]]:
    g = GraphHarness()
    bridge = g.add(Bridge, {"port": 0, "client_publish": ["robot/estop"], "queue_size": 1000}, name="viz")
    try:
        yield g, bridge
    finally:
        g.close()


def client(bridge: Bridge) -> FoxgloveClient:
    return FoxgloveClient(f"ws://127.0.0.1:{bridge.port}").open()


PLAN = ScanPlan(stamp_ns=5, mode="sweep", region_mm=(0.0, 0.0, 10.0, 10.0), spacing_mm=5.0, speed_mm_s=10.0,
                lines=2, estimated_duration_s=3.0,
                waypoints=[PlanWaypoint(x_mm=0.0, y_mm=0.0, z_mm=5.0, speed_mm_s=10.0, kind="contact", line=0),
                           PlanWaypoint(x_mm=10.0, y_mm=0.0, z_mm=5.0, speed_mm_s=10.0, kind="contact", line=0)])
MAP = StiffnessMap(stamp_ns=6, unit="kPa", x_mm=[1.0, 3.0], y_mm=[1.0], stiffness=[20.0, math.nan], count=[3, 0],
                   spread=[0.1, math.nan], samples=3)


def test_channels_carry_the_json_schema_and_payloads_arrive_as_json(graph: tuple[GraphHarness, Bridge]) -> None:
    g, bridge = graph
    heights = ProbeHeights(stamp_ns=1, seq=1, h_mm=(1.0, 2.0, 3.0, 4.0), raw=(0.0,) * 4, d_in_mm=0.5,
                           tilt_rad=0.01)
    g.publish("probe/heights", heights)
    c = client(bridge)
    c.pump_until(lambda: c.channel("probe/heights") is not None, 5, "the probe/heights channel")
    assert c.ws is not None and c.ws.subprotocol == SUBPROTOCOL
    ch = c.channel("probe/heights")
    assert ch is not None
    assert (ch["encoding"], ch["schemaName"], ch["schemaEncoding"]) == ("json", "ProbeHeights", "jsonschema")
    schema = json.loads(ch["schema"])
    assert schema["type"] == "object" and "$ref" not in ch["schema"]
    assert schema["properties"]["h_mm"]["items"] == {"type": "number"}  # plottable element by element
    c.subscribe("probe/heights")
    pose = RobotPose(stamp_ns=2, x_mm=1.0, y_mm=math.nan, z_mm=3.0)
    g.publish("robot/pose", pose)
    c.pump_until(lambda: c.channel("robot/pose") is not None, 5, "robot/pose advertised when first heard")
    c.subscribe("robot/pose")
    # The SDK takes a subscribe op on its own thread: a message published before it lands has no subscriber
    # and is (rightly) not sent, so publish again until both have arrived rather than guess when it landed.
    def both() -> bool:
        if not (c.of("probe/heights") and c.of("robot/pose")):
            g.publish("probe/heights", heights)
            g.publish("robot/pose", pose)
            return False
        return True
    c.pump_until(both, 5, "both messages")
    assert c.of("probe/heights")[-1].data == json.loads(msgspec.json.encode(heights))
    got = c.of("robot/pose")[-1]
    assert got.data["y_mm"] is None and got.data["x_mm"] == 1.0  # NaN has no JSON spelling: null
    assert got.log_time == c.of("robot/pose")[-1].log_time > 0
    c.close()


def test_a_client_joining_late_gets_the_latched_map_and_plan(graph: tuple[GraphHarness, Bridge]) -> None:
    g, bridge = graph
    g.add(ScanViews, name="views")
    g.publish("robot/plan", PLAN, latched=True)
    g.publish("map/stiffness", MAP, latched=True)
    g.publish("map/inclusions", Inclusions(stamp_ns=7, unit="kPa", baseline=20.0, inclusions=[]), latched=True)
    for _ in range(5):
        g.publish("robot/pose", RobotPose(stamp_ns=8, x_mm=1.0, y_mm=2.0, z_mm=3.0))
    early = client(bridge)  # watching before the late one: it sees the re-sent values too (the SDK cannot
    early.pump_until(lambda: early.channel("viz/plan") is not None, 5, "adverts")  # address one client)
    early.subscribe()
    late = client(bridge)
    wanted = ("robot/plan", "map/stiffness", "viz/map", "viz/plan", "viz/map_image")
    late.pump_until(lambda: all(late.channel(t) for t in wanted), 5, "every latched topic advertised")
    late.subscribe()
    late.pump_until(lambda: all(late.of(t) for t in wanted), 5, "the latched values")
    assert late.of("robot/plan")[0].data == json.loads(msgspec.json.encode(PLAN))
    assert late.of("map/stiffness")[0].data["stiffness"] == [20.0, None]
    assert late.of("viz/map")[0].data["column_count"] == 2
    assert not late.of("robot/pose")  # not latched: nothing old is replayed
    stats = bridge.stats()
    assert stats["clients"][str(bridge.server._clients and max(bridge.server._clients))]["latched_resent"] >= 5
    late.close()
    early.close()


def test_a_full_queue_drops_and_counts_instead_of_blocking_the_bus(graph: tuple[GraphHarness, Bridge]) -> None:
    g, bridge = graph
    server = bridge.server
    server._queue_size = 3
    g.publish("robot/pose", RobotPose(stamp_ns=1, x_mm=0.0, y_mm=0.0, z_mm=0.0))
    c = client(bridge)
    c.pump_until(lambda: c.channel("robot/pose") is not None, 5, "robot/pose advertised")
    c.subscribe()
    wait_until(lambda: server.stats()["clients"], 5)
    release, busy = threading.Event(), threading.Event()
    send = server._send

    def stuck(key: tuple[str, str], payload: bytes, stamp_ns: int) -> None:  # the sender thread held up
        busy.set()  # (a slow transcode, a GIL-starved thread)
        release.wait(10)
        send(key, payload, stamp_ns)

    server._send = stuck  # type: ignore[method-assign]
    g.publish("robot/pose", RobotPose(stamp_ns=2, x_mm=0.0, y_mm=0.0, z_mm=0.0))
    wait_until(busy.is_set, 5)
    for i in range(9):  # the bus side goes on at once: 3 queued, 6 dropped
        g.publish("robot/pose", RobotPose(stamp_ns=10 + i, x_mm=0.0, y_mm=0.0, z_mm=0.0))
    stats = server.stats()
    assert stats["topics"]["robot/pose"]["dropped"] == 6
    assert stats["clients"][str(next(iter(server._clients)))]["dropped"] == {"robot/pose": 6}
    release.set()
    c.pump_until(lambda: any(m.data["stamp_ns"] == 12 for m in c.of("robot/pose")), 5, "the queued ones")
    assert [m.data["stamp_ns"] for m in c.of("robot/pose")][-3:] == [10, 11, 12]
    assert bridge.counters()["robot/pose"].gaps == 0  # nothing lost on the bus side
    c.close()


def test_a_stalled_client_and_an_abrupt_disconnect_leave_the_bridge_serving(
        graph: tuple[GraphHarness, Bridge]) -> None:
    g, bridge = graph
    g.publish("map/stiffness", MAP)
    stalled, gone, reader = client(bridge), client(bridge), client(bridge)
    for c in (stalled, gone, reader):
        c.pump_until(lambda c=c: c.channel("map/stiffness") is not None, 5, "adverts")
        c.subscribe()
    wait_until(lambda: len(bridge.server.stats()["clients"]) == 3, 5)
    gone.close_abruptly()
    big = msgspec.structs.replace(MAP, x_mm=[float(i) for i in range(2000)], y_mm=[1.0],
                                  stiffness=[1.0] * 2000, count=[1] * 2000, spread=[0.0] * 2000)
    for i in range(400):  # ~16 MB of JSON that the stalled client never reads
        g.publish("map/stiffness", msgspec.structs.replace(big, stamp_ns=100 + i))
    reader.pump_until(lambda: any(m.data["stamp_ns"] == 499 for m in reader.of("map/stiffness")), 20,
                      "the last map at the reading client")
    clients = bridge.server.stats()["clients"]
    assert sum(not c["connected"] for c in clients.values()) == 1  # the dropped connection, noticed
    assert bridge.stats()["bus"]["map/stiffness"]["gaps"] == 0
    stalled.close_abruptly()
    reader.close()


def test_a_client_may_publish_the_estop_and_nothing_else(graph: tuple[GraphHarness, Bridge]) -> None:
    g, bridge = graph
    c = client(bridge)
    c.pump(0.1)
    assert c.server_info["capabilities"] == ["clientPublish"]
    c.advertise(1, "robot/estop", "EStop")
    c.advertise(2, "robot/pose", "RobotPose")  # not in client_publish: refused
    c.publish(2, {"stamp_ns": 1, "x_mm": 0.0, "y_mm": 0.0, "z_mm": 0.0})
    c.publish(1, {"reason": "from foxglove"})
    c.publish(1, {"engaged": "yes"})  # wrong type: refused and counted, the bridge goes on

    def arrived() -> bool:
        g.advance(0.05)
        return bridge.client_errors == 1 and bool(g.published("robot/estop"))

    wait_until(arrived, 5)
    (stop,) = g.published("robot/estop")
    assert stop == EStop(stamp_ns=stop.stamp_ns, engaged=True, reason="from foxglove") and stop.stamp_ns > 0
    assert not [m for m in g.published("robot/pose")]
    c.close()


def test_loopback_only_unless_asked() -> None:
    with pytest.raises(ParamError, match="allow_remote"):
        Bridge(params={"host": "0.0.0.0", "port": 0}, transport=GraphHarness().bus.transport())


def test_a_port_in_use_is_one_line_with_the_hint() -> None:
    """`palpa viz` with its port taken printed a 30-line traceback (issue 39): now one line (the CLI prints a
    PalpaError so) that names the address and says --port 0."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(palpa.PalpaError) as info:
            Bridge(params={"port": port}, transport=GraphHarness().bus.transport())
    text = str(info.value)
    assert f"cannot listen on 127.0.0.1:{port}" in text and "in use" in text and "--port 0" in text
    assert "\n" not in text and "Traceback" not in text


def test_palpa_viz_serves_a_running_graph_and_survives_a_vanished_client(
        ipc_bus: BusAddress, procs: ProcessGroup, env_for: Callable[..., dict[str, str]]) -> None:
    """The CLI as a user runs it, on a real bus beside a talker process."""
    env = env_for(ipc_bus)
    procs.start(palpa_cmd("run", "nodes.demo:Talker", "-p", "rate_hz=50"), env=env)
    viz = procs.start(palpa_cmd("viz", "--port", "0", "chatter"), env=env)
    line = viz.wait_for_output("palpa viz ready", timeout=30)
    url = line.split("ready ", 1)[1].split()[0]
    first = FoxgloveClient(url).open()
    first.pump_until(lambda: first.channel("chatter") is not None, 10, "chatter advertised")
    assert {c["topic"] for c in first.channels.values()} <= {"chatter", "_palpa/log", "_palpa/viz/stats"}
    first.subscribe("chatter")
    first.pump_until(lambda: len(first.of("chatter")) >= 3, 10, "chatter messages")
    assert first.of("chatter")[-1].data["text"].startswith("hello")
    first.close_abruptly()
    second = FoxgloveClient(url).open()
    second.pump_until(lambda: second.channel("chatter") is not None, 10, "chatter advertised again")
    second.subscribe("chatter")
    second.pump_until(lambda: len(second.of("chatter")) >= 3, 10, "chatter after the first client vanished")
    second.close()
    assert viz.stop(10) == 0, viz.output()


def test_a_viewer_joins_a_simulated_scan_midway(tmp_path: Path) -> None:
    """launch/scan_sim.yaml viz:=true on a tiny raster, its nodes (bridge and views as the file declares them)
    composed in memory: a client watching from the start, another joining while the scan is held midway (the test
    stops advancing simulated time once the first map is out, so the late client joins a graph that is still
    running, however loaded the machine), getting the latched plan and map, then vanishing; the scan then ends
    normally and the watcher still gets what came after."""
    from palpa.launch import load_launch, parse_overrides
    from palpa.targets import load_node_class
    from palpa.timing.clock import MockClock
    from palpa.timing.compose import Composition
    from palpa.timing.simclock import ClockSource

    plan = load_launch(REPO / "launch" / "scan_sim.yaml", parse_overrides([
        "viz:=true", "viz_port:=0", "spacing_mm:=4.0", "region_mm:=[10.0, 14.0, 22.0, 22.0]",
        f"geometry:={REPO / 'phantoms' / 'measured' / 'airfloat_tumours.yaml'}", f"output_dir:={tmp_path}"]),
        run_dir=tmp_path)
    comp = Composition(clock=MockClock(1_700_000_000_000_000_000), heartbeat_s=0)
    watcher = late = None
    try:
        for spec in plan.nodes:
            assert spec.target is not None
            cls = load_node_class(spec.target)
            if cls is not ClockSource:  # the composition is the clock
                comp.add(cls, spec.name, spec.params, required=spec.required)
        (bridge,) = [n for n in comp.nodes if isinstance(n, Bridge)]
        maps: list[StiffnessMap] = []
        probe = comp.adopt(palpa.Node(name="probe", transport=comp.transport(), clock=comp.clock, heartbeat_s=0))
        probe.subscribe("map/stiffness", StiffnessMap, maps.append)
        watcher = FoxgloveClient(bridge.url).open()
        watcher.pump_until(lambda: watcher.server_info, 5, "serverInfo")
        wait_until(lambda: maps, 60, "a first map in the composed scan", step=comp.step)
        assert not comp.ended  # held midway: the scan goes on only when the test steps it again

        def watch() -> bool:
            watcher.subscribe()
            watcher.pump(0.05)
            return bool(watcher.of("map/stiffness"))

        wait_until(watch, 10, "the first map at the watching client")
        late = FoxgloveClient(bridge.url).open()

        def join() -> bool:
            late.subscribe()
            late.pump(0.05)
            return bool(late.of("map/stiffness") and late.of("robot/plan") and late.of("viz/plan"))

        wait_until(join, 10, "the latched map and plan at the late client")
        plan_msg = late.of("robot/plan")[0].data
        assert plan_msg["region_mm"] == [10.0, 14.0, 22.0, 22.0] and plan_msg["waypoints"]
        late.close_abruptly()
        poses_then = len(watcher.of("robot/pose"))
        wait_until(lambda: comp.ended, 60, "the scan to end", step=comp.step)
        assert comp.ended == [("scanner", 0)], comp.ended
        watcher.pump_until(lambda: len(watcher.of("robot/pose")) > poses_then and watcher.of("viz/tf")
                           and watcher.of("viz/map"), 10, "poses after the late client vanished, viz/tf and viz/map")
    finally:
        for c in (watcher, late):
            if c is not None:
                c.close()
        comp.close()
    assert (tmp_path / "map.npz").stat().st_size > 0  # the map node, closed after the scan, wrote its files


class _WithService(Bridge):
    def services(self) -> list[foxglove.Service]:
        return [foxglove.Service("ping", schema=foxglove.ServiceSchema("Ping"), handler=lambda req: b"{}")]


def test_the_services_hook_advertises_what_a_subclass_offers() -> None:
    g = GraphHarness()
    bridge = g.add(_WithService, {"port": 0}, name="viz")
    c = client(bridge)
    try:
        c.pump_until(lambda: bool(c.server_info), 5, "serverInfo")
        assert "services" in c.server_info["capabilities"]
        assert "clientPublish" not in c.server_info["capabilities"]  # client_publish is empty
    finally:
        c.close()
        g.close()
