"""Every launch file in launch/ is smoke-tested: ``--check`` passes, and launched it produces a message on each
topic it should, then stops on Ctrl-C with exit 0 (or ends by itself with the expected code).

Adding a launch file? Add its entry to SMOKE: arg overrides for a quick run, the topics it must produce, and a
timeout. The test fails for a file without an entry.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

import palpa
from palpa.cli.main import main as cli_main
from palpa.node.node import RawMessage
from tests.procs import ProcessGroup, palpa_cmd, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

REPO = Path(__file__).resolve().parent.parent
LAUNCH_DIR = REPO / "launch"


@dataclass(frozen=True)
class Smoke:
    args: list[str] = field(default_factory=list)
    """Arg overrides (name:=value) for a quick run."""
    topics: list[str] = field(default_factory=list)
    """Topics that must each carry at least one message."""
    timeout: float = 30.0
    """Seconds to see every topic (and, after Ctrl-C, to stop)."""
    exit_code: int = 0
    """Expected exit code (a file whose required node ends it may end by itself)."""
    prepare: Callable[[Path], list[str]] | None = None
    """Makes what the file needs in a temporary folder (e.g. a recording) and returns more arg overrides."""
    launched_by: str = ""
    """A test file that already launches this file as processes and checks these topics in its recording: here
    only ``--check`` runs (one process launch per file, not two)."""


def synthetic_scan_bag(tmp: Path) -> list[str]:
    """A 3 s recording of a probe held over the flat 26.4 kPa phantom, made with the real sim nodes."""
    from nodes.probe.fibre_reader import FibreReader
    from nodes.probe.pressure_controller import PressureController
    from nodes.scanner.static_pose import StaticPose
    from palpa.record.testing import Rec, write_bag
    from palpa.testing import GraphHarness

    phantom = str(REPO / "phantoms" / "flat_26k.yaml")
    g = GraphHarness()
    g.add(StaticPose, {"z_mm": 21.0})
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 36.0})
    g.add(FibreReader, {"phantom": phantom})
    g.advance(3.0)
    import msgspec

    from messages import ScanPlan

    plan = ScanPlan(stamp_ns=g.clock.now_ns(), mode="sweep", region_mm=(20.0, 20.0, 40.0, 40.0), spacing_mm=2.0,
                    speed_mm_s=10.0, lines=1, estimated_duration_s=3.0, waypoints=[])
    first = g.raw[0].header.stamp
    recs = [Rec("robot/plan", first, msgspec.msgpack.encode(plan), 1, "ScanPlan", "scanner", latched=True)]
    seq: dict[str, int] = {}
    for raw in g.raw:
        if raw.topic in ("robot/pose", "probe/heights", "pressure/state"):
            seq[raw.topic] = seq.get(raw.topic, 0) + 1
            recs.append(Rec(raw.topic, raw.header.stamp, raw.payload, seq[raw.topic], raw.header.type, raw.header.node))
    g.close()
    bag = write_bag(tmp / "synthetic.mcap", recs)
    return [f"bag:={bag}", f"geometry:={REPO / 'phantoms' / 'measured' / 'flat_26k.yaml'}", "calibration:=",
            "rate:=1.0"]


SMOKE: dict[str, Smoke] = {
    "talker_listener.yaml": Smoke(args=["rate:=20.0"], topics=["chatter", "chatter_len"], timeout=30),
    # launched as processes, and these topics checked, by the tests named in launched_by
    "airfloat_sim.yaml": Smoke(topics=["robot/pose", "pressure/state", "probe/heights", "probe/status",
                                       "stiffness/sample"], launched_by="tests/test_airfloat_nodes.py"),
    # touch-off is tested in tests/test_touchoff*.py: the smokes plan at the phantom's known height. time_scale is
    # a ceiling (the lockstep clock runs at the slowest node's pace): on an idle machine, a smoke waits less
    "scan_sim.yaml": Smoke(args=["region_mm:=[20.0, 20.0, 30.0, 30.0]", "spacing_mm:=5.0", "touchoff:=off",
                                 "time_scale:=20.0"],
                           topics=["robot/pose", "robot/plan", "robot/scan_status", "probe/heights", "pressure/state",
                                   "stiffness/sample", "map/stiffness", "map/inclusions"],
                           launched_by="tests/test_compose.py"),
    # the rig's file: --check as is; the run with every driver simulated (never the default robot address)
    "scan_ur.yaml": Smoke(args=["scanner_driver:=sim", "fibre_driver:=sim", "pressure_driver:=sim",
                                "phantom:=phantoms/airfloat_tumours.yaml",
                                "region_mm:=[20.0, 20.0, 30.0, 30.0]", "spacing_mm:=5.0", "speed_mm_s:=20.0"],
                          topics=["robot/pose", "probe/heights", "pressure/state", "stiffness/sample",
                                  "robot/scan_status"], timeout=60),
    "scan_camera_sim.yaml": Smoke(args=["region_mm:=[14.0, 14.0, 18.0, 18.0]", "touchoff:=off", "time_scale:=20.0"],
                                  topics=["robot/pose", "robot/plan", "camera/indenters", "stiffness/sample",
                                          "map/stiffness", "robot/scan_status"], timeout=60),
    "scan_adaptive_sim.yaml": Smoke(args=["region_mm:=[36.0, 33.0, 48.0, 45.0]", "initial:=2", "max_probes:=5",
                                          "touchoff:=off", "time_scale:=20.0"],
                                    topics=["robot/pose", "probe/heights", "stiffness/sample", "planner/mean",
                                            "planner/std"], timeout=90),
    "scan_adaptive_camera_sim.yaml": Smoke(args=["region_mm:=[12.0, 12.0, 20.0, 20.0]", "seed_spacing_mm:=0",
                                                 "initial:=2", "max_probes:=4", "touchoff:=off",
                                                 "time_scale:=20.0"],
                                           topics=["robot/pose", "camera/indenters", "stiffness/sample",
                                                   "planner/mean", "planner/std"], timeout=90),
    # the rig's file, launched as processes with the ur_rtde driver against the UR emulator there
    "scan_adaptive_camera_ur.yaml": Smoke(topics=["robot/pose", "camera/indenters", "stiffness/sample",
                                                  "planner/mean"], launched_by="tests/test_adaptive_camera_ur.py"),
    "scan_adaptive_ur.yaml": Smoke(topics=["robot/pose", "probe/heights", "stiffness/sample", "planner/mean"],
                                   launched_by="tests/test_adaptive_airfloat_ur.py"),
    "replay_scan.yaml": Smoke(prepare=synthetic_scan_bag, topics=["probe/heights", "stiffness/sample", "map/stiffness"],
                              timeout=60),
    # idle until asked: a probe_at is exercised by tests/test_service_cli.py
    "probe_sim.yaml": Smoke(topics=["robot/pose", "robot/scan_status", "probe/heights", "pressure/state"],
                            launched_by="tests/test_service_cli.py"),
    "camera_sim.yaml": Smoke(args=["cycles:=0", "speed_mm_s:=4.0"], topics=["robot/pose", "robot/scan_status", "camera/status", "camera/indenters", "camera/debug", "stiffness/sample"], timeout=40),
}

FILES = sorted(p.name for p in LAUNCH_DIR.glob("*.yaml"))


def test_every_launch_file_has_a_smoke_entry() -> None:
    missing = [f for f in FILES if f not in SMOKE]
    stale = [f for f in SMOKE if f not in FILES]
    assert not missing, f"add an entry to SMOKE in {__file__} for: {', '.join(missing)}"
    assert not stale, f"SMOKE names launch files that do not exist: {', '.join(stale)}"


@pytest.mark.parametrize("name", FILES)
def test_launch_file_runs_and_produces_its_topics(name: str, procs: ProcessGroup, tmp_path: Path) -> None:
    entry = SMOKE.get(name)
    if entry is None:
        pytest.fail(f"launch/{name} has no entry in SMOKE ({__file__})")
    if entry.launched_by:
        check(LAUNCH_DIR / name, entry.args)
        text = (REPO / entry.launched_by).read_text()
        assert f"launch/{name}" in text or f'"{name}"' in text, f"{entry.launched_by} does not launch {name}"
        assert all(t in text for t in entry.topics), f"{entry.launched_by} does not check all of {entry.topics}"
        return
    if entry.prepare is not None:
        entry = dataclasses.replace(entry, args=[*entry.args, *entry.prepare(tmp_path)])
    smoke(LAUNCH_DIR / name, entry, procs, tmp_path)


@pytest.mark.parametrize("transport", ["ipc", "tcp"])
def test_custom_node_example_launches(procs: ProcessGroup, tmp_path: Path, transport: str) -> None:
    """examples/custom_node: a node from a file outside the package, found through the file's python_path;
    over the default ipc bus and over tcp with OS-chosen ports (--bus-address)."""
    extra = ["--bus-address", "tcp://127.0.0.1"] if transport == "tcp" else []
    smoke(REPO / "examples" / "custom_node" / "launch.yaml", Smoke(args=["suffix:=?!"], topics=["chatter", "shout"]),
          procs, tmp_path, extra)
    address = (tmp_path / "run" / "bus.address").read_text()
    assert address.startswith("pub=tcp://127.0.0.1:" if transport == "tcp" else "pub=ipc:///tmp/palpa-")


def check(file: Path, args: list[str], extra: list[str] | None = None) -> None:
    """``palpa launch --check`` in this process (the command line's own entry point, from the repository as the
    launch runs): validation and every node class imported, without another interpreter's start-up."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(REPO), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main(["launch", "--check", str(file), *(extra or []), *args])
    assert code == 0, err.getvalue()
    assert "nodes:" in out.getvalue(), out.getvalue()


def smoke(file: Path, entry: Smoke, procs: ProcessGroup, tmp_path: Path, extra: list[str] | None = None) -> None:
    """--check, launch, wait for a message on each topic (a node of our own on the run's bus), Ctrl-C."""
    check(file, entry.args, [a for a in extra or [] if a == "--in-process"])
    run_dir = tmp_path / "run"
    proc = procs.start(palpa_cmd("launch", str(file), "--run-dir", str(run_dir), "--no-progress", *(extra or []),
                                 *entry.args), cwd=str(REPO))
    address_file = run_dir / "bus.address"
    wait_until(lambda: address_file.exists() and address_file.read_text().endswith("\n") or
               proc.popen.poll() is not None, 20, "the launcher's bus.address")
    assert address_file.exists(), proc.output()
    seen: set[str] = set()

    def on_raw(raw: RawMessage) -> None:
        seen.add(raw.topic)

    with palpa.Node(name="smoke", bus=address_file.read_text().strip(), heartbeat_s=0) as probe:
        probe.subscribe_raw("", on_raw)
        with contextlib.suppress(AssertionError):  # what is missing is named below, with the launch's output
            wait_until(lambda: set(entry.topics) <= seen or proc.popen.poll() is not None, entry.timeout,
                       f"a message on each of {entry.topics}", step=lambda: probe.spin_once(0.1))
    missing = sorted(set(entry.topics) - seen)
    assert not missing, f"no message on {missing} within {entry.timeout} s:\n{proc.output()}"
    proc.signal(signal.SIGINT)
    code = proc.wait(entry.timeout)
    assert code == entry.exit_code, proc.output()
