"""The graph tools as a new user meets them: ``topic pub`` refuses what it cannot send faithfully, the tools
find the running launch without ``--bus``, and every "nothing heard" names the bus that was tried."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

import palpa
from messages import EStop, Text
from palpa.cli.common import message_from_yaml
from palpa.cli.main import main
from palpa.current import announce, find_bus, withdraw
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from tests.launching import launched, wait_nodes_up
from tests.procs import ProcessGroup, palpa_cmd, short_ipc_base, wait_until


@contextmanager
def graph_node(address: BusAddress, setup: str, heard: list[EStop] | None = None) -> Iterator[None]:
    """A heartbeating node on ``address`` spun in a thread: ``setup`` 'estop' subscribes robot/estop (EStop; what
    it hears goes in ``heard``), 'talker' publishes Text on chatter."""
    stop = threading.Event()
    ready = threading.Event()

    def body() -> None:
        with palpa.Node(name=f"{setup}_node", bus=address, heartbeat_s=0.2) as node:
            pub = None
            if setup == "estop":
                node.subscribe("robot/estop", EStop, heard.append if heard is not None else lambda m: None)
            else:
                pub = node.publisher("chatter", Text)
            ready.set()
            while not stop.is_set():
                node.spin_once(0.05)
                if pub is not None:
                    pub.publish(Text(text="hello"))

    t = threading.Thread(target=body, daemon=True)
    t.start()
    assert ready.wait(10)
    try:
        yield
    finally:
        stop.set()
        t.join(10)


@pytest.fixture
def live_bus() -> Iterator[BusAddress]:
    with Bus(BusAddress.parse(f"ipc://{short_ipc_base()}")) as b:
        assert b.address is not None
        yield b.address


def test_pub_refuses_a_misspelt_field_with_a_suggestion(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(palpa.PalpaError, match=r"EStop has no field 'engage' \(did you mean 'engaged'\?\)"):
        message_from_yaml("EStop", "{engage: false}")
    # through the CLI: exit 1 before any bus is touched
    assert main(["topic", "pub", "robot/estop", "EStop", "{engaged: false, reasn: test}",
                 "--bus", f"ipc://{short_ipc_base()}"]) == 1
    assert "did you mean 'reason'" in capsys.readouterr().err
    assert message_from_yaml("EStop", "{engaged: false}").engaged is False


@pytest.mark.system
def test_pub_fails_when_no_bus_answers(capsys: pytest.CaptureFixture[str]) -> None:
    nowhere = f"ipc://{short_ipc_base()}"
    assert main(["topic", "pub", "chatter", "Text", "{text: hi}", "--bus", nowhere]) == 1
    err = capsys.readouterr().err
    assert "no bus answered" in err and nowhere in err and "nothing was sent" in err


@pytest.mark.system
def test_pub_warns_on_a_type_the_graph_does_not_use(live_bus: BusAddress,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    with graph_node(live_bus, "estop"):
        assert main(["topic", "pub", "robot/estop", "Text", "{text: stop}", "--bus", str(live_bus)]) == 0
        err = capsys.readouterr().err
        assert "'robot/estop' carries EStop" in err and "estop_node" in err
        assert main(["topic", "pub", "robot/nothing", "Text", "{text: x}", "--bus", str(live_bus)]) == 0
        assert "nothing subscribes to 'robot/nothing'" in capsys.readouterr().err


@pytest.mark.system
def test_echo_strips_the_slash_and_names_the_missing_publisher(live_bus: BusAddress,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    with graph_node(live_bus, "talker"):
        assert main(["topic", "echo", "/chatter", "-n", "1", "--timeout", "10", "--bus", str(live_bus)]) == 0
        out = capsys.readouterr()
        assert "using 'chatter'" in out.err and "text: hello" in out.out
        assert main(["topic", "echo", "chater", "-n", "1", "--timeout", "3", "--bus", str(live_bus)]) == 1
        assert "publishes 'chater' (did you mean 'chatter'?)" in capsys.readouterr().err


@pytest.mark.system
def test_tools_find_the_current_launch_then_a_run_dir(live_bus: BusAddress, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("PALPA_BUS", raising=False)
    monkeypatch.setenv("PALPA_CURRENT", str(tmp_path / "launches"))
    run_dir = tmp_path / "runs" / "20260101-000000"
    run_dir.mkdir(parents=True)
    (run_dir / "bus.address").write_text(f"{live_bus}\n")
    entry = announce(live_bus, run_dir)
    assert (tmp_path / "runs" / "latest").resolve() == run_dir.resolve()
    assert find_bus() == (live_bus, f"the running launch in {run_dir.resolve()}")
    with graph_node(live_bus, "talker"):
        assert main(["node", "list", "--wait", "1"]) == 0
        out = capsys.readouterr()
        assert "talker_node" in out.out
        assert out.err.splitlines()[0] == f"palpa node: bus {live_bus} (the running launch in {run_dir.resolve()})"
    withdraw(entry)
    assert find_bus()[1].startswith("the default bus") and not (tmp_path / "launches").exists()
    assert find_bus(run=tmp_path / "runs" / "latest") == (live_bus, f"the launch in {tmp_path / 'runs' / 'latest'}")
    elsewhere = tmp_path / "scratch" / "x"
    elsewhere.mkdir(parents=True)
    withdraw(announce(live_bus, elsewhere))  # --run-dir scratch/x: no scratch/latest beside it
    assert not (tmp_path / "scratch" / "latest").exists()


@pytest.mark.system
def test_nothing_heard_names_the_bus(capsys: pytest.CaptureFixture[str]) -> None:
    nowhere = f"ipc://{short_ipc_base()}"
    assert main(["node", "list", "--wait", "0.2", "--bus", nowhere]) == 1
    err = capsys.readouterr().err
    assert "no nodes heard in 0.2 s on" in err and nowhere.removeprefix("ipc://") in err and "(--bus)" in err
    assert main(["topic", "list", "--wait", "0.2", "--bus", nowhere]) == 1
    assert "(--bus)" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.system
def test_readme_commands_find_a_launch_from_a_second_terminal(procs: ProcessGroup, tmp_path: Path) -> None:
    """``palpa node list`` exactly as the README prints it, in another process with no --bus and no PALPA_BUS."""
    env = {k: v for k, v in os.environ.items() if k != "PALPA_BUS"}
    with launched(procs, "launch/talker_listener.yaml", tmp_path / "run") as (proc, node):
        current = Path(os.environ["PALPA_CURRENT"])
        wait_until(lambda: any(current.glob("*.json")), 30, "the launcher's entry among the running launches")
        wait_nodes_up(node, {"talker", "listener"}, 30, proc)  # as a user would: after the graph came up
        out = subprocess.run(palpa_cmd("node", "list"), env=env, capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert "talker" in out.stdout and "listener" in out.stdout
        proc.signal(signal.SIGINT)
        assert proc.wait(30) == 0
    assert not current.exists()  # withdrawn when the launch ended (the folder goes with its last entry)


def test_palpa_run_help_without_a_target(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["run", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "MODULE:CLASS" in out and "--param" in out and "working directory" in out


@pytest.mark.system
def test_palpa_run_imports_from_the_working_directory_and_lists_parameters(tmp_path: Path) -> None:
    folder = Path(__file__).resolve().parent.parent / "examples" / "custom_node"
    env = {**os.environ, "PYTHONPATH": str(folder.parents[1])}  # palpa itself, not the example's folder
    # like the installed `palpa` script: sys.path[0] is the script's folder, not the working directory
    entry = tmp_path / "palpa_script.py"
    entry.write_text("import sys\nfrom palpa.cli.main import main\nsys.exit(main())\n")
    res = subprocess.run([sys.executable, str(entry), "run", "shouter:Shouter", "--help"], cwd=folder, env=env,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "parameters (-p NAME=VALUE;" in res.stdout and "suffix: str = '!'" in res.stdout


def test_palpa_run_misspelt_parameter_gets_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "nodes.demo:Talker", "-p", "rate_h=5", "--bus", f"ipc://{short_ipc_base()}"])
    assert code == 2
    assert "unknown field `rate_h` (did you mean 'rate_hz'?)" in capsys.readouterr().err


def test_schema_lists_type_names_and_suggests_a_close_one(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.split()[:2] == ["EStop", "messages.robot"] for line in lines)
    assert main(["schema", "Estop"]) == 1
    assert "did you mean 'EStop'?" in capsys.readouterr().err


@pytest.mark.system
def test_a_node_that_cannot_start_says_why_in_one_line(ipc_bus: BusAddress,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    # on a live bus: without one the node would first wait out the bus handshake, which is not what is tested
    code = main(["run", "nodes.probe.fibre_reader:FibreReader", "-p", "driver=sim", "-p", "phantom=no_such.yaml",
                 "--bus", str(ipc_bus)])
    err = capsys.readouterr().err
    assert code == 2 and "phantom file 'no_such.yaml' does not exist" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
