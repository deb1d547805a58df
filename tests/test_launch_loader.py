"""Loading launch files: native types, args and overrides, substitutions, includes, the resolved file, the schema,
``--check`` output. All in-process: no bus, no children."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from palpa.cli.launch import describe
from palpa.errors import LaunchError
from palpa.launch import json_schema, load_launch, parse_overrides
from palpa.launch.plan import RECORDER_TARGET
from palpa.net.address import BusAddress

REPO = Path(__file__).resolve().parent.parent


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text))
    return path


def test_scalars_are_yaml_1_2_native_types(tmp_path: Path) -> None:
    f = write(tmp_path / "a.yaml", """
        nodes:
          - name: probe
            cmd: ["true"]
            params:
              i: 3
              f: 2.5
              e: 1e3
              b: true
              n: null
              s: yes
              o: off
              q: "7"
              date: 2024-01-02
              hexa: 0x1F
              inf: .inf
              nested: {list: [1, two, 3.0]}
    """)
    p = load_launch(f).nodes[0].params
    assert p["i"] == 3 and type(p["i"]) is int
    assert p["f"] == 2.5 and p["e"] == 1000.0 and type(p["e"]) is float
    assert p["b"] is True and p["n"] is None
    assert p["s"] == "yes" and p["o"] == "off" and p["q"] == "7" and p["date"] == "2024-01-02"
    assert p["hexa"] == 31 and math.isinf(p["inf"])
    assert p["nested"] == {"list": [1, "two", 3.0]}


def test_args_defaults_overrides_and_substitutions(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPA_T_HOST", "rig-1")
    monkeypatch.delenv("PALPA_T_MISSING", raising=False)
    f = write(tmp_path / "sub" / "g.yaml", """
        args:
          - {name: rate, default: 10.0}
          - {name: count, default: 0}
          - {name: label, default: "every $(arg rate) Hz"}
          - {name: flags, default: [a, b]}
        nodes:
          - name: talker
            node: nodes.demo:Talker
            params: {rate_hz: $(arg rate), count: $(arg count), text: $(arg label)}
          - name: tool
            cmd: ["$(dirname)/tool.sh", "--host=$(env PALPA_T_HOST)", "$(env PALPA_T_MISSING fall back)",
                  "$(run_dir)/out", "echo $$(date)", "flags=$(arg flags)"]
            params: {flags: $(arg flags), on: $(arg count)}
    """)
    (f.parent / "tool.sh").write_text("#!/bin/sh\n")
    (f.parent / "tool.sh").chmod(0o755)  # --check refuses a cmd program that does not exist
    plan = load_launch(f, parse_overrides(["count:=7", "rate:=2.5"]), run_dir=tmp_path / "r")
    talker, tool = plan.nodes
    assert talker.params == {"rate_hz": 2.5, "count": 7, "text": "every 2.5 Hz"}
    assert plan.args == {"rate": 2.5, "count": 7, "label": "every 2.5 Hz", "flags": ["a", "b"]}
    assert tool.cmd is not None
    assert tool.cmd == [f"{f.parent}/tool.sh", "--host=rig-1", "fall back", f"{tmp_path / 'r'}/out",
                        "echo $(date)", 'flags=["a", "b"]']
    assert tool.params == {"flags": ["a", "b"], "on": 7}
    assert plan.node_params["talker"] == {"rate_hz": 2.5, "text": "every 2.5 Hz", "count": 7}


def test_overrides_are_parsed_as_yaml() -> None:
    got = parse_overrides(["a:=3", "b:=2.0", "c:=true", "d:=[1, x]", "e:='3'", "f:=hello world", "g:=",
                           "h:={k: 1}", "url:=tcp://h:1"])
    assert got == {"a": 3, "b": 2.0, "c": True, "d": [1, "x"], "e": "3", "f": "hello world", "g": "",
                   "h": {"k": 1}, "url": "tcp://h:1"}
    with pytest.raises(LaunchError, match="expected name:=value"):
        parse_overrides(["rate=3"])


def test_includes_with_args_namespaces_and_python_path(tmp_path: Path) -> None:
    write(tmp_path / "lib" / "nodes_here.py", """
        import palpa

        class Echo(palpa.Node):
            class Params(palpa.Params):
                gain: float = 1.0
    """)
    write(tmp_path / "parts" / "arm.yaml", """
        args:
          - {name: side}
          - {name: gain, default: 1.0}
        python_path: [../lib]
        nodes:
          - {name: "echo_$(arg side)", node: nodes_here:Echo, params: {gain: $(arg gain)}, namespace: arm}
    """)
    top = write(tmp_path / "top.yaml", """
        args:
          - {name: g, default: 4.0}
        include:
          - {file: parts/arm.yaml, args: {side: left, gain: $(arg g)}, namespace: left}
          - {file: parts/arm.yaml, args: {side: right}, namespace: right}
        nodes:
          - {name: talker, node: nodes.demo:Talker}
    """)
    plan = load_launch(top)
    assert [(n.name, n.namespace, n.params) for n in plan.nodes] == [
        ("echo_left", "left/arm", {"gain": 4.0}),
        ("echo_right", "right/arm", {"gain": 1.0}),
        ("talker", "", {}),
    ]
    assert plan.python_path == [str(tmp_path / "lib")]
    assert str(tmp_path / "lib") not in sys.path  # the launcher's import path is restored after validation
    assert len(plan.files) == 3 and plan.files[0].endswith("top.yaml") and plan.files[2].endswith("arm.yaml")


def test_a_whole_arg_keeps_its_type_so_a_list_in_a_string_field_is_an_error(tmp_path: Path) -> None:
    f = write(tmp_path / "l.yaml", """
        args: [{name: flags, default: [a, b]}]
        nodes: [{name: tool, cmd: [prog, $(arg flags)]}]
    """)
    with pytest.raises(LaunchError, match=r"l.yaml:3:34: nodes\[0\].cmd\[1\]: expected `str`, got `array`"):
        load_launch(f)


def test_anchors_and_merge_keys(tmp_path: Path) -> None:
    f = write(tmp_path / "m.yaml", """
        nodes:
          - &base {name: a, cmd: ["true"], sigterm_timeout: 1.0, output: log}
          - <<: *base
            name: b
            output: screen
    """)
    a, b = load_launch(f).nodes
    assert (b.name, b.cmd, b.sigterm_timeout, b.output) == ("b", ["true"], 1.0, "screen")
    assert a.output == "log"


def test_resolved_file_loads_back_to_the_same_graph(tmp_path: Path) -> None:
    plan = load_launch(REPO / "launch" / "talker_listener.yaml", {"rate": 3.0}, run_dir=tmp_path / "r")
    again_file = write(tmp_path / "resolved.yaml", plan.to_yaml())
    again = load_launch(again_file, run_dir=tmp_path / "r")
    assert [n.as_dict() for n in again.nodes] == [n.as_dict() for n in plan.nodes]
    assert again.args == plan.args and again.bus == plan.bus


def test_bus_section_and_overrides(tmp_path: Path) -> None:
    default = load_launch(REPO / "launch" / "talker_listener.yaml").bus_request()
    assert default.pub.startswith("ipc:///tmp/palpa-") and len(default.latch) < 100
    plan = load_launch(REPO / "launch" / "talker_listener.yaml")
    # fresh per run, never twice the same in one process (1 000 draws of 4 hex digits alone would collide)
    assert len({plan.bus_request().pub for _ in range(1000)} | {default.pub}) == 1001
    tcp = load_launch(write(tmp_path / "t.yaml", "bus: {transport: tcp, latched: [a/b], hwm: 50}\nnodes: []\n"))
    assert tcp.bus.latched == ["a/b"] and tcp.bus.hwm == 50
    assert tcp.bus_request() == BusAddress("tcp://127.0.0.1:*", "tcp://127.0.0.1:*", "tcp://127.0.0.1:*")
    fixed = load_launch(write(tmp_path / "f.yaml", "bus: {transport: tcp, endpoint: 'tcp://127.0.0.1:7000'}\n"))
    assert fixed.bus_request().latch == "tcp://127.0.0.1:7002"
    ipc = load_launch(write(tmp_path / "i.yaml", "bus: {endpoint: /tmp/pl-x}\n"))
    assert ipc.bus_request().sub == "ipc:///tmp/pl-x.sub"
    assert ipc.bus_request("tcp://127.0.0.1").pub == "tcp://127.0.0.1:*"


def test_record_section(tmp_path: Path) -> None:
    plan = load_launch(write(tmp_path / "r.yaml", """
        record: {topics: ["chatter.*"], exclude: ["_palpa/.*"], split_size_mb: 5}
        nodes: [{name: talker, node: nodes.demo:Talker}]
    """), run_dir=tmp_path / "run")
    rec = plan.recorder()
    assert rec is not None and rec.target == RECORDER_TARGET and rec.name == "recorder"
    assert rec.params == {"output": str(tmp_path / "run" / "recording.mcap"), "topics": ["chatter.*"],
                          "exclude": ["_palpa/.*"], "split_size_mb": 5, "launch_file":
                          str(tmp_path / "run" / "launch.resolved.yaml")}
    everything = load_launch(write(tmp_path / "all.yaml", "record: true\nnodes: []\n")).recorder()
    assert everything is not None and everything.params["topics"] == []
    assert load_launch(write(tmp_path / "off.yaml", "record: false\n")).recorder() is None
    with pytest.raises(LaunchError, match="'recorder' is taken"):
        load_launch(write(tmp_path / "clash.yaml", "record: true\nnodes: [{name: recorder, cmd: [x]}]\n"))


@pytest.mark.system
def test_json_schema_comes_from_the_same_definitions() -> None:
    schema = json_schema()
    defs = schema["$defs"]
    node = defs["NodeDecl"]
    assert node["additionalProperties"] is False and node["required"] == ["name"]
    assert set(node["properties"]) >= {"name", "node", "cmd", "params", "remap", "namespace", "env", "respawn",
                                       "respawn_delay", "respawn_max_retries", "required", "sigterm_timeout",
                                       "sigkill_timeout", "output"}
    # numbers and booleans also accept a whole-string $(arg name)
    timeout = node["properties"]["sigterm_timeout"]
    assert timeout["anyOf"][0] == {"type": "number", "minimum": 0.0, "maximum": 1e9} and timeout["default"] == 5.0
    assert timeout["anyOf"][1] == {"type": "string", "pattern": r"^\$\(arg [A-Za-z][A-Za-z0-9_-]*\)$"}
    assert set(defs["LaunchFile"]["properties"]) == {"description", "args", "python_path", "include", "prepare",
                                                     "nodes", "bus", "record", "progress", "viz", "in_process"}
    out = subprocess.run([sys.executable, "-m", "palpa.cli.main", "launch", "--schema"], capture_output=True,
                         text=True, timeout=60, check=True)
    assert json.loads(out.stdout) == json.loads(json.dumps(schema))


def test_check_output_shows_params_with_defaults_and_origin(tmp_path: Path) -> None:
    plan = load_launch(REPO / "launch" / "talker_listener.yaml", {"count": 5})
    text = describe(plan)
    assert text.splitlines()[0].endswith("talker_listener.yaml: ok (2 nodes)")
    assert "params: {rate_hz: 10.0, text: hello, count: 5}" in text
    assert "talker_listener.yaml:" in text and "flags: [required]" in text


def test_a_shipped_scan_can_be_included_with_one_more_node(tmp_path: Path) -> None:
    """docs/custom-node.md's worked example: the included scan brings its recording and progress bar; a setting
    of the including file wins over the included one."""
    scan = REPO / "launch" / "scan_sim.yaml"
    top = write(tmp_path / "my_scan.yaml", f"""\
        include:
          - file: {scan}
            args: {{spacing_mm: 6.0}}
        nodes:
          - {{name: listener, node: nodes.demo:Listener}}
        """)
    plan = load_launch(top, run_dir=tmp_path / "run")
    assert plan.progress_topic == "robot/scan_status"
    assert plan.record is not None and plan.record.exclude == ["_palpa/clock.*", "_palpa/tick/.*", "_palpa/lockstep"]
    assert [n.name for n in plan.nodes][-2:] == ["scanner", "listener"]
    assert plan.node_params["scanner"]["spacing_mm"] == 6.0
    own = write(tmp_path / "quiet.yaml", f"""\
        record: false
        progress: {{topic: my/progress}}
        include: [{{file: {scan}}}]
        nodes: []
        """)
    plan = load_launch(own, run_dir=tmp_path / "run")
    assert plan.record is None and plan.progress_topic == "my/progress"


def test_replay_takes_the_geometry_from_the_recording(tmp_path: Path) -> None:
    """launch/replay_scan.yaml's defaults (measured geometry, calibration) come from the launch file the recording
    carries, not the demo's."""
    from palpa.record.recorder import Recorder
    from palpa.testing import NodeHarness

    geo = REPO / "phantoms" / "measured" / "flat_26k.yaml"
    scanned = tmp_path / "scan.resolved.yaml"
    scanned.write_text("nodes:\n  - name: estimator\n    node: nodes.probe.stiffness_estimator:AirfloatStiffnessEstimator\n"
                       f"    params: {{geometry: {geo}, calibration: ''}}\n")
    bag = tmp_path / "run" / "recording.mcap"
    bag.parent.mkdir()
    NodeHarness(Recorder, {"output": str(bag), "launch_file": str(scanned)}).close()
    plan = load_launch(REPO / "launch" / "replay_scan.yaml", {"bag": str(bag.parent)}, run_dir=tmp_path / "r")
    assert plan.node_params["estimator"]["geometry"] == str(geo)
    assert plan.node_params["estimator"]["calibration"] == ""

    bare = tmp_path / "bare.mcap"
    NodeHarness(Recorder, {"output": str(bare)}).close()  # `palpa record`: no launch file in it
    with pytest.raises(LaunchError, match=r"carries no launch file .*give geometry:=VALUE instead"):
        load_launch(REPO / "launch" / "replay_scan.yaml", {"bag": str(bare)}, run_dir=tmp_path / "r")
    plan = load_launch(REPO / "launch" / "replay_scan.yaml", {"bag": str(bare), "geometry": str(geo),
                                                                "calibration": ""}, run_dir=tmp_path / "r")
    assert plan.node_params["estimator"]["geometry"] == str(geo)


def test_prepare_commands_are_substituted_and_kept_in_the_resolved_file(tmp_path: Path) -> None:
    """scan_sim.yaml's prepare step measures the phantom given on the command line into the run directory, and
    the estimator and scanner read what it writes (never the phantom)."""
    plan = load_launch(REPO / "launch" / "scan_sim.yaml", {"phantom": "phantoms/specimens/dome_6_3.yaml"},
                       run_dir=tmp_path)
    measured = str(tmp_path / "measured_geometry.yaml")
    assert plan.prepare == [["python", "-m", "models.geometry", "measure", "phantoms/specimens/dome_6_3.yaml",
                             "--error-mm", "0.2", "-o", measured]]
    params = {n.name: n.params for n in plan.nodes}
    assert params["estimator"]["geometry"] == measured and params["scanner"]["geometry"] == measured
    again = tmp_path / "resolved.yaml"
    again.write_text(plan.to_yaml())
    assert load_launch(again, {}, run_dir=tmp_path).prepare == plan.prepare
