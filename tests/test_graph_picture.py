"""``palpa graph`` (issue 42): the graph of a launch file from its node classes' declared topics and services, with
nothing started, and of a running graph from heartbeats; drawn with networkx and matplotlib, direct topics marked."""

from __future__ import annotations

from pathlib import Path

import pytest

from palpa.cli.main import main
from palpa.graph import GraphModel, graph_of_heartbeats, render
from palpa.launch.topics import declared_services
from palpa.runtime_msgs import Heartbeat
from tests.test_launch_smoke import REPO

SIX = {"clock", "pressure", "fibre", "estimator", "map", "scanner"}


def test_the_scan_launch_file_drawn_without_starting_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "g.svg"
    assert main(["graph", "launch", str(REPO / "launch" / "scan_sim.yaml"), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "7 nodes" in said and "camera/indenters: subscribed by scanner, published by no node" in said
    svg = out.read_text()
    for name in [*SIX, "recorder", "probe/heights", "stiffness/sample", "robot/pose", "map/inclusions", "map/save",
                 "RobotScanner"]:
        assert name in svg, name
    assert svg.count("#e07000") == 1  # no direct topic here: orange only in the legend
    png = tmp_path / "g.png"
    assert main(["graph", "launch", str(REPO / "launch" / "scan_sim.yaml"), "spacing_mm:=4", "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_model_of_a_launch_file_has_its_edges_and_direct_topics(tmp_path: Path) -> None:
    from palpa.graph import graph_of_plan
    from palpa.launch import load_launch
    from palpa.targets import load_node_class

    plan = load_launch(REPO / "launch" / "scan_sim.yaml", {}, run_dir=tmp_path)
    g = graph_of_plan(plan, load_node_class)
    assert set(g.nodes) == SIX | {"recorder"}
    assert ("fibre", "probe/heights") in g.publishes and ("estimator", "probe/heights") in g.subscribes
    assert ("scanner", "robot/pose") in g.publishes and ("fibre", "robot/pose") in g.subscribes
    assert ("map", "map/save") in g.serves and not g.direct
    # the scanner registers its services itself (since its state machine): they are read from its class too
    assert {s for n, s in g.serves if n == "scanner"} == {"scanner/probe_at", "scanner/pause", "scanner/resume",
                                                         "scanner/abort"}
    launch = tmp_path / "direct.yaml"
    launch.write_text("nodes:\n"
                      "  - {name: talker, node: nodes.demo:Talker, transport: {direct: [chatter]}}\n"
                      "  - {name: listener, node: nodes.demo:Listener, remap: {chatter: talk}}\n")
    g = graph_of_plan(load_launch(launch, {}, run_dir=tmp_path), load_node_class)
    assert g.direct == {"chatter"} and ("listener", "talk") in g.subscribes
    assert g.unheard() == ["talk"]


def test_declared_services() -> None:
    from nodes.mapping.map_aggregator import MapAggregator

    assert declared_services(MapAggregator, "left") == {"serves": ["left/map/save"], "calls": []}
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from nodes.scanner.robot_scanner import RobotScanner

    # probe_at's service is kept (self.control.probe = self.service(...)): found in an assignment too
    assert declared_services(RobotScanner) == {
        "serves": ["scanner/abort", "scanner/pause", "scanner/probe_at", "scanner/resume"], "calls": []}
    assert declared_services(AdaptivePlanner, remap={"scanner/probe_at": "arm/probe_at"})["calls"] == [
        "arm/probe_at"]


def _beat(node: str, pub: dict[str, str], sub: dict[str, str], **kw: object) -> Heartbeat:
    return Heartbeat(node=node, pid=1, host="h", publishes=pub, subscribes=sub, counters={}, sent={}, uptime_s=1.0,
                     **kw)  # type: ignore[arg-type]


def test_a_running_graph_from_heartbeats_with_direct_topics_marked(tmp_path: Path) -> None:
    beats = {"talker": _beat("talker", {"chatter": "Text", "_palpa/log": "LogRecord"}, {}, direct=["chatter"]),
             "listener": _beat("listener", {"chatter_len": "Text"},
                               {"chatter": "Text", "listener/reset/request*": "*"},
                               services={"listener/reset": "Trigger -> TriggerResult"}),
             "operator": _beat("operator", {"listener/reset/request": "Trigger"},
                               {"listener/reset/reply/operator*": "*"})}
    g = graph_of_heartbeats(beats, "test")
    assert g.topics == {"chatter": "Text", "chatter_len": "Text"}  # runtime topics left out
    assert g.direct == {"chatter"} and ("listener", "listener/reset") in g.serves
    assert g.calls == {("operator", "listener/reset")}  # the request and reply topics are the service's edges
    svg = render(g, tmp_path / "g.svg").read_text()
    assert "chatter" in svg and "[Text]" in svg and "Trigger -&gt; TriggerResult" in svg
    assert svg.count("fill: #ffffff; stroke: #e07000") == 1  # the direct topic's box
    assert svg.count("fill: none; stroke: #e07000; stroke-width: 2.6; stroke-linecap: round") == 2  # its edges
    plain = graph_of_heartbeats({**beats, "talker": _beat("talker", {"chatter": "Text"}, {})})
    assert render(plain, tmp_path / "p.svg").read_text().count("#e07000") == 1


def test_graph_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["graph", "launch", str(REPO / "launch" / "scan_sim.yaml"), "-o", str(tmp_path / "g.jpg")]) == 1
    assert "suffix: .png, .svg or .pdf" in capsys.readouterr().err
    assert main(["graph", "lunch", "x.yaml", "-o", str(tmp_path / "g.png")]) == 1
    assert "expected `palpa graph launch FILE" in capsys.readouterr().err
    with pytest.raises(Exception, match="no nodes"):
        render(GraphModel(), tmp_path / "e.png")
