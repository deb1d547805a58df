"""The start gate (palpa.startgate): a composed simulation starts before the launcher's node checks and prepare
step, imports its code meanwhile, and builds nothing until they have passed; the other start-up savings of issue 40
(the bus's attach mark, the one-verb parser)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import zmq

from palpa import env as palpa_env
from palpa.cli import main as cli_main
from palpa.net.bus import Bus
from palpa.net.direct import ATTACH_MARK, SubscriberSet
from palpa.startgate import open_gate, release, wait_for_go
from tests.procs import ProcessGroup
from tests.test_launch_supervisor import TESTS, launch, launch_log, write


def _gate(monkeypatch: pytest.MonkeyPatch) -> int:
    r, w = open_gate()
    monkeypatch.setenv(palpa_env.START_GATE, str(r))
    return w


def test_go_lets_the_child_through_onto_the_bus_it_names(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(palpa_env.BUS, raising=False)
    release(_gate(monkeypatch), "ipc:///tmp/x.pub;sub=ipc:///tmp/x.sub")
    assert wait_for_go()
    assert os.environ[palpa_env.BUS] == "ipc:///tmp/x.pub;sub=ipc:///tmp/x.sub"
    assert palpa_env.START_GATE not in os.environ  # not passed on to the child's own children


def test_a_start_called_off_builds_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(palpa_env.BUS, "ipc:///tmp/before")
    release(_gate(monkeypatch), None)
    assert not wait_for_go()
    assert os.environ[palpa_env.BUS] == "ipc:///tmp/before"


def test_without_a_gate_the_child_goes_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(palpa_env.START_GATE, raising=False)
    assert wait_for_go()


def test_the_proxy_attach_mark_is_no_listener() -> None:
    subs = SubscriberSet()
    subs.note(b"\x01" + ATTACH_MARK)
    subs.note(b"\x01robot/")
    assert subs.prefixes == {b"robot/"}
    assert not subs.covers(ATTACH_MARK)


def test_a_launch_imports_only_its_own_verb(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[str | None] = []
    real = cli_main.build_parser
    monkeypatch.setattr(cli_main, "build_parser", lambda only=None: asked.append(only) or real(only))
    with pytest.raises(SystemExit):
        cli_main.main(["--debug", "graph", "--help"])
    with pytest.raises(SystemExit):
        cli_main.main(["lunch"])  # a typo gets the whole list of verbs
    assert asked == ["graph", None]
    assert set(real("launch")._subparsers._group_actions[0].choices) == {"launch"}  # type: ignore[union-attr]


@pytest.mark.system
def test_a_publisher_attaching_to_the_bus_hears_a_subscription_at_once(tmp_path: Path) -> None:
    """Without the mark, a publisher attaching while nobody subscribes waits its whole grace for subscriptions."""
    from palpa.net.address import BusAddress

    bus = Bus(BusAddress(f"ipc://{tmp_path}/p", f"ipc://{tmp_path}/s", f"ipc://{tmp_path}/l"))
    address = bus.start()
    ctx = zmq.Context()
    xpub = ctx.socket(zmq.XPUB)
    try:
        xpub.connect(address.pub)
        assert xpub.poll(10_000), "no subscription from the proxy"
        assert xpub.recv() == b"\x01" + ATTACH_MARK
    finally:
        xpub.close(0)
        ctx.term()
        bus.stop()


def _composed(tmp_path: Path, prepare: str, params: str) -> Path:
    return write(tmp_path, f"""
        python_path: [{json.dumps(str(TESTS))}]
        in_process: true
        prepare:
          - [python, -c, {json.dumps(prepare)}]
        nodes:
          - name: needs
            node: launch_node_classes:NeedsFile
            env: {{PALPA_SIM_CLOCK: "1"}}
            required: true
            params: {params}
    """)


@pytest.mark.system
def test_the_composed_graph_starts_first_and_builds_once_the_prepare_step_has_run(procs: ProcessGroup,
                                                                                 tmp_path: Path) -> None:
    target = tmp_path / "made.txt"
    slow = f"import time, pathlib; time.sleep(1.0); pathlib.Path({str(target)!r}).write_text('by prepare')"
    run = tmp_path / "run"
    proc = launch(procs, _composed(tmp_path, slow, json.dumps({"path": str(target)})), run, "--no-progress")
    assert proc.wait(60) == 0, proc.output()
    assert "read: by prepare" in proc.output()
    log = launch_log(run)
    assert log.index("started sim") < log.index("prepare:")  # it imported its code while prepare ran


@pytest.mark.system
def test_a_failed_prepare_step_calls_the_composed_start_off(procs: ProcessGroup, tmp_path: Path) -> None:
    run = tmp_path / "run"
    proc = launch(procs, _composed(tmp_path, "import sys; sys.exit(3)", json.dumps({"path": "/nonexistent"})),
                  run, "--no-progress")
    assert proc.wait(60) == 1, proc.output()
    assert "exited 3" in proc.output()
    assert "the launcher called the start off: no node was built" in (run / "sim.log").read_text()


@pytest.mark.system
def test_a_bad_parameter_of_a_composed_node_is_refused_at_its_line(procs: ProcessGroup, tmp_path: Path) -> None:
    run = tmp_path / "run"
    file = _composed(tmp_path, "pass", "{path: x, speed: 3}")
    proc = launch(procs, file, run, "--no-progress")
    assert proc.wait(60) == 1, proc.output()
    assert f"{file}:" in proc.output() and "has no parameter 'speed'" in proc.output()
    assert "the launcher called the start off: no node was built" in (run / "sim.log").read_text()


def _running_with(token: str) -> list[int]:
    """Pids of this user's processes whose command line holds ``token``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if token.encode() in (entry / "cmdline").read_bytes():
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


@pytest.mark.system
def test_a_failed_check_stops_the_prepare_step_running_beside_it(procs: ProcessGroup, tmp_path: Path) -> None:
    """The prepare step starts with the checks (palpa.launch.prepare): a bad parameter ends the launch at once and
    leaves no prepare command running."""
    token = f"palpa-prepare-{os.getpid()}-{tmp_path.name}"
    run = tmp_path / "run"
    file = _composed(tmp_path, f"import time; {token!r}; time.sleep(120)", "{path: x, speed: 3}")
    try:
        proc = launch(procs, file, run, "--no-progress")
        assert proc.wait(60) == 1, proc.output()
        assert "has no parameter 'speed'" in proc.output()
        assert "prepare:" in launch_log(run)  # it had started
        assert _running_with(token) == []
    finally:
        for pid in _running_with(token):
            os.kill(pid, 9)


@pytest.mark.system
def test_exit_now_runs_the_exit_handlers_and_flushes_what_was_printed() -> None:
    """palpa.exiting: the launcher and the composition end without the interpreter's teardown, but not without
    their exit handlers (the bus's last messages are flushed by one) or their buffered output."""
    import subprocess

    code = ("import atexit, sys; from palpa.exiting import exit_now; "
            "atexit.register(lambda: print('handler ran')); sys.stdout.write('buffered '); exit_now(3)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          cwd=str(TESTS.parent), check=False)
    assert done.returncode == 3
    assert done.stdout == "buffered handler ran\n"
