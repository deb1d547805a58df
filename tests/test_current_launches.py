"""Which graph a tool addresses (palpa.current): the one running launch, never a guess among several, never a dead
launch's leftover entry (issue 39: with two graphs running, an e-stop went to the one started last)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from palpa.cli.main import main
from palpa.current import announce, find_bus, launches_dir, running_launches, withdraw
from palpa.errors import BusError
from palpa.net.address import BusAddress

A = BusAddress.parse("ipc:///tmp/palpa-test-a/bus")
B = BusAddress.parse("ipc:///tmp/palpa-test-b/bus")


@pytest.fixture
def runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.delenv("PALPA_BUS", raising=False)
    monkeypatch.setenv("PALPA_CURRENT", str(tmp_path / "launches"))
    for name, bus in (("a", A), ("b", B)):
        (tmp_path / "runs" / name).mkdir(parents=True)
        (tmp_path / "runs" / name / "bus.address").write_text(f"{bus}\n")
    return tmp_path / "runs"


def test_one_launch_is_used_two_are_named_and_not_guessed(runs: Path) -> None:
    a = announce(A, runs / "a")
    assert find_bus() == (A, f"the running launch in {runs / 'a'}")
    b = announce(B, runs / "b")  # started last: a guess would take it
    with pytest.raises(BusError, match="2 launches are running; not guessing") as info:
        find_bus()
    text = str(info.value)
    assert f"--run {runs / 'a'}   (bus {A}" in text and f"--run {runs / 'b'}   (bus {B}" in text
    assert find_bus(run=runs / "a") == (A, f"the launch in {runs / 'a'}")
    assert find_bus(run=Path("b")) == (B, f"the launch in {runs / 'b'}")  # a running launch's run name
    assert find_bus(bus=str(A)) == (A, "--bus")
    withdraw(b)
    assert find_bus() == (A, f"the running launch in {runs / 'a'}")
    withdraw(a)
    assert find_bus()[1] == "the default bus; no launch is running"


def test_an_unknown_run_name_is_an_error_naming_the_file_it_looked_for(runs: Path) -> None:
    announce(A, runs / "a")
    with pytest.raises(BusError, match=r"--run c: no c/bus.address \(is it the run directory of a launch\?\)"):
        find_bus(run=Path("c"))


def test_a_dead_or_reused_launchers_entry_does_not_count_and_is_removed(runs: Path) -> None:
    a = announce(A, runs / "a")
    folder = launches_dir()
    dead = folder / "4194311-1.json"  # above Linux's largest pid (2^22): no such process
    dead.write_text(json.dumps({"bus": str(B), "pid": 2**22 + 7, "started": 1, "run_dir": str(runs / "b")}))
    reused = folder / f"{os.getppid()}-9.json"  # a live process, but not the one that wrote it (another start)
    reused.write_text(json.dumps({"bus": str(B), "pid": os.getppid(), "started": -1, "run_dir": str(runs / "b")}))
    (folder / "garbage.json").write_text("{not json")
    assert find_bus() == (A, f"the running launch in {runs / 'a'}")
    assert [launch.run_dir for launch in running_launches()] == [str(runs / "a")]
    assert sorted(p.name for p in folder.iterdir()) == [a.name]
    withdraw(a)
    assert not folder.exists()


def test_palpa_run_does_not_join_a_guessed_graph_either(runs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    announce(A, runs / "a")
    announce(B, runs / "b")
    assert main(["run", "nodes.demo:Talker"]) == 1
    assert "2 launches are running; not guessing" in capsys.readouterr().err


def test_palpa_bus_in_the_environment_is_explicit_and_wins(runs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    announce(A, runs / "a")
    announce(B, runs / "b")
    monkeypatch.setenv("PALPA_BUS", str(B))
    assert find_bus() == (B, "$PALPA_BUS")
