"""The CLI with two graphs running (issue 39): a bare `topic pub robot/estop` or `node list` names both launches and
asks for --run instead of acting on the one started last; with --run it addresses that one only, and says which
on its first stderr line. Two live ipc buses in this process, the tools driven in-process."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import pytest

from messages import EStop
from palpa.cli.main import main
from palpa.current import announce, withdraw
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from tests.procs import short_ipc_base
from tests.test_cli_graph_tools import graph_node

pytestmark = pytest.mark.system


def test_two_graphs_the_tools_ask_which_and_address_only_the_one_named(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("PALPA_BUS", raising=False)
    monkeypatch.setenv("PALPA_CURRENT", str(tmp_path / "launches"))
    heard: dict[str, list[EStop]] = {"a": [], "b": []}
    with ExitStack() as stack:
        buses = {}
        for name in ("a", "b"):
            bus = stack.enter_context(Bus(BusAddress.parse(f"ipc://{short_ipc_base()}")))
            assert bus.address is not None
            buses[name] = bus.address
            run_dir = tmp_path / "runs" / name
            run_dir.mkdir(parents=True)
            (run_dir / "bus.address").write_text(f"{bus.address}\n")
            stack.enter_context(graph_node(bus.address, "estop", heard[name]))
        entries = {name: announce(buses[name], tmp_path / "runs" / name) for name in ("a", "b")}

        assert main(["topic", "pub", "robot/estop", "EStop", "{engaged: true, reason: test}"]) == 1
        err = capsys.readouterr().err
        assert "2 launches are running; not guessing" in err and "--run RUN" in err
        assert f"--run {tmp_path / 'runs' / 'a'}" in err and f"--run {tmp_path / 'runs' / 'b'}" in err
        assert main(["node", "list", "--wait", "0.5"]) == 1
        assert "not guessing" in capsys.readouterr().err

        assert main(["topic", "pub", "robot/estop", "EStop", "{engaged: true, reason: test}",
                     "--run", str(tmp_path / "runs" / "a")]) == 0
        err = capsys.readouterr().err
        assert err.splitlines()[0] == f"palpa topic: bus {buses['a']} (the launch in {tmp_path / 'runs' / 'a'})"
        assert main(["node", "list", "--run", "b", "--wait", "1.5"]) == 0  # by the run's name
        out = capsys.readouterr()
        assert out.err.splitlines()[0].startswith(f"palpa node: bus {buses['b']} (the launch in ") and "estop_node" in out.out

        assert main(["node", "list", "--bus", str(buses["b"]), "--wait", "1.5"]) == 0
        assert "palpa node: bus" not in capsys.readouterr().err  # named on the command line: not said again
        withdraw(entries["b"])  # graph b ended: one candidate left, used and named
        assert main(["node", "list", "--wait", "1.5"]) == 0
        assert capsys.readouterr().err.splitlines()[0].startswith(f"palpa node: bus {buses['a']} (the running launch")
        withdraw(entries["a"])
    assert [m.reason for m in heard["a"]] == ["test"] and heard["b"] == []
