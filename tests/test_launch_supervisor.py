"""The launcher as a process: staged shutdown, respawn with backoff, required nodes, no orphans, output, progress.

Each test writes a small launch file into its tmp dir (helper programs: tests/launch_nodes.py), runs
``palpa launch`` with ``--run-dir`` under it, and reads the launcher's output and the run directory.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import textwrap
import time
from datetime import datetime
from pathlib import Path

import pytest

from palpa.launch import load_launch
from palpa.launch.process import process_alive
from palpa.net.address import BusAddress
from tests.procs import Proc, ProcessGroup, palpa_cmd, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system

TESTS = Path(__file__).resolve().parent
HELPER = TESTS / "launch_nodes.py"
REPO = TESTS.parent


def prog(kind: str, *args: str) -> str:
    """A YAML flow list running one helper program."""
    return json.dumps([sys.executable, str(HELPER), kind, *args])


def write(tmp_path: Path, text: str, name: str = "graph.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def launch(procs: ProcessGroup, file: Path, run_dir: Path, *extra: str) -> Proc:
    return procs.start(palpa_cmd("launch", str(file), "--run-dir", str(run_dir), *extra), cwd=str(REPO))


def launch_log(run_dir: Path) -> str:
    path = run_dir / "launch.log"
    return path.read_text() if path.exists() else ""


def starts(run_dir: Path, name: str) -> list[tuple[datetime, int]]:
    """(time, pid) of every start of ``name``, from launch.log."""
    out = []
    for m in re.finditer(rf"^(\S+) INFO started {name} pid (\d+)", launch_log(run_dir), re.M):
        out.append((datetime.strptime(m.group(1), "%H:%M:%S.%f"), int(m.group(2))))
    return out


def wait_started(run_dir: Path, *names: str, timeout: float = 20.0) -> dict[str, int]:
    wait_until(lambda: all(starts(run_dir, n) for n in names), timeout, f"{names} started:\n{launch_log(run_dir)}")
    return {n: starts(run_dir, n)[-1][1] for n in names}


def wait_gone(pids: list[int], timeout: float = 10.0) -> None:
    wait_until(lambda: not any(process_alive(p) for p in pids), timeout,
               f"processes {[p for p in pids if process_alive(p)]} to be gone")


def test_stubborn_node_escalates_to_sigkill_and_is_named(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: stubborn, cmd: {prog("stubborn")}, sigterm_timeout: 0.5, sigkill_timeout: 0.5}}
          - {{name: steady, cmd: {prog("steady")}}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    proc.wait_for_output("[stubborn] stubborn ready", 20)
    proc.wait_for_output("[steady] tick", 20)
    pids = wait_started(run_dir, "stubborn", "steady")
    t0 = time.monotonic()
    proc.signal(signal.SIGINT)
    code = proc.wait(20)
    elapsed = time.monotonic() - t0
    out = proc.output()
    assert code == 0, out  # escalation is reported, not a failure of the graph
    assert "stubborn did not stop within 0.5 s of SIGINT: sending SIGTERM" in out
    assert "stubborn did not stop within 0.5 s of SIGTERM: sending SIGKILL" in out
    assert re.search(r"! stubborn\s+needed SIGKILL", out), out
    assert re.search(r"  steady\s+stopped on SIGINT", out), out
    assert elapsed >= 1.0, "SIGKILL came before both timeouts had passed"
    assert not process_alive(pids["stubborn"]) and not process_alive(pids["steady"])
    assert "steady: stopping cleanly" in (run_dir / "steady.log").read_text()


def test_second_ctrl_c_skips_the_waiting(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: stubborn, cmd: {prog("stubborn")}, sigterm_timeout: 30, sigkill_timeout: 30}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    proc.wait_for_output("[stubborn] stubborn ready", 20)
    proc.signal(signal.SIGINT)
    proc.wait_for_output("stopping: stopped by SIGINT", 10)
    proc.signal(signal.SIGINT)
    proc.wait_for_output("SIGINT again", 10)
    proc.signal(signal.SIGINT)
    assert proc.wait(20) == 0  # far less than the 60 s the timeouts alone would take
    assert re.search(r"! stubborn\s+needed SIGKILL", proc.output())


def test_crash_loop_backs_off_gives_up_and_the_graph_keeps_running(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - name: crasher
            cmd: {prog("crash", "3")}
            respawn: true
            respawn_delay: 0.2
            respawn_max_retries: 3
          - {{name: steady, cmd: {prog("steady")}, output: log}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    proc.wait_for_output("crasher: giving up after 3 retries (last: exit code 3)", 30)
    steady_pid = wait_started(run_dir, "steady")["steady"]
    times = [t for t, _ in starts(run_dir, "crasher")]
    assert len(times) == 4, launch_log(run_dir)
    out = proc.output()
    for delay, retry in (("0.20", "1/3"), ("0.40", "2/3"), ("0.80", "3/3")):
        assert f"crasher ended (exit code 3); respawning in {delay} s (retry {retry})" in out, out
    gaps = [(b - a).total_seconds() for a, b in zip(times, times[1:], strict=False)]
    for gap, planned in zip(gaps, (0.2, 0.4, 0.8), strict=True):
        assert gap >= planned - 0.005, (gaps, launch_log(run_dir))  # never sooner than the backoff says
    # the rest of the graph is untouched: same steady process, still ticking, launcher still up
    ticks = (run_dir / "steady.log").read_text().count("tick")
    wait_until(lambda: (run_dir / "steady.log").read_text().count("tick") > ticks + 2, 10, "more ticks")
    assert proc.popen.poll() is None and process_alive(steady_pid)
    assert [pid for _, pid in starts(run_dir, "steady")] == [steady_pid]
    assert "[steady]" not in proc.output()  # output: log keeps it off the screen
    proc.signal(signal.SIGINT)
    assert proc.wait(20) == 1  # a node failed for good
    assert "launch ended: stopped by SIGINT; failed: crasher; exit code 1" in proc.output()


@pytest.mark.parametrize("code", [0, 4])
def test_required_node_ends_the_launch_with_its_exit_code(procs: ProcessGroup, tmp_path: Path, code: int) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: steady, cmd: {prog("steady")}}}
          - {{name: quitter, cmd: {prog("quit", str(code), "0.5")}, required: true}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    assert proc.wait(30) == code
    out = proc.output()
    assert f"stopping: required node quitter ended (exit code {code})" in out
    assert re.search(r"steady\s+stopped on SIGINT", out)
    assert "steady: stopping cleanly" in (run_dir / "steady.log").read_text()


def test_crash_without_respawn_is_reported_and_the_rest_runs_on(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: crasher, cmd: {prog("crash", "5")}}}
          - {{name: steady, cmd: {prog("steady")}}}
          - {{name: envprobe, cmd: {prog("env")}, params: {{gain: 2.5, axes: [x, y]}}, env: {{EXTRA: "yes"}},
              remap: {{a: b}}, namespace: left}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    proc.wait_for_output("crasher ended (exit code 5); it is not required, the graph keeps running", 20)
    line = proc.wait_for_output("[envprobe] env ", 20)
    steady = wait_started(run_dir, "steady")["steady"]
    proc.wait_for_output("[steady] tick 3", 20)
    assert process_alive(steady) and proc.popen.poll() is None
    env = json.loads(line.split("[envprobe] env ", 1)[1])
    assert json.loads(env["PALPA_PARAMS"]) == {"gain": 2.5, "axes": ["x", "y"]}
    assert json.loads(env["PALPA_REMAP"]) == {"a": "b"} and env["PALPA_NAMESPACE"] == "left"
    assert env["PALPA_RUN_DIR"] == str(run_dir.resolve()) and env["PALPA_NODE_NAME"] == "envprobe"
    assert env["PYTHONUNBUFFERED"] == "1" and env["EXTRA"] == "yes"
    assert BusAddress.parse(env["PALPA_BUS"]) == BusAddress.parse((run_dir / "bus.address").read_text())
    proc.signal(signal.SIGINT)
    assert proc.wait(20) == 1
    out = proc.output()
    assert "failed: crasher" in out and re.search(r"! crasher\s+ended by itself \(exit code 5\)", out)
    # every line of a node is in its log, unprefixed; the resolved file loads again to the same graph
    assert "crash: starting and failing at once" in (run_dir / "crasher.log").read_text()
    again = load_launch(run_dir / "launch.resolved.yaml")
    assert [n.name for n in again.nodes] == ["crasher", "steady", "envprobe"]
    assert again.nodes[2].params == {"gain": 2.5, "axes": ["x", "y"]} and again.nodes[2].namespace == "left"


def test_sigkilled_launcher_leaves_no_process_behind(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: talker, node: nodes.demo:Talker, params: {{rate_hz: 5.0}}}}
          - {{name: steady, cmd: {prog("steady")}}}
          - {{name: parent, cmd: {prog("parent")}}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    line = proc.wait_for_output("[parent] parent pid", 30)
    pids = list(wait_started(run_dir, "talker", "steady", "parent").values())
    grandchild = int(line.rsplit(" ", 1)[1])
    reaper = int(re.search(r"reaper pid (\d+)", launch_log(run_dir)).group(1))  # type: ignore[union-attr]
    assert all(process_alive(p) for p in [*pids, grandchild, reaper])
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    wait_gone([*pids, grandchild, reaper])


def test_pdeathsig_alone_kills_the_children(procs: ProcessGroup, tmp_path: Path) -> None:
    """Without the reaper process, the kernel's PR_SET_PDEATHSIG still takes every direct child down."""
    file = write(tmp_path, f"""
        nodes:
          - {{name: talker, node: nodes.demo:Talker, params: {{rate_hz: 5.0}}}}
          - {{name: steady, cmd: {prog("steady")}}}
    """)
    run_dir = tmp_path / "run"
    code = ("import sys; from palpa.launch import Supervisor, load_launch; "
            f"sys.exit(Supervisor(load_launch({str(file)!r}, run_dir={str(run_dir)!r}), reaper=False).run())")
    proc = procs.start([sys.executable, "-c", code], cwd=str(REPO))
    pids = list(wait_started(run_dir, "talker", "steady").values())
    proc.wait_for_output("[steady] tick", 20)
    assert "reaper" not in launch_log(run_dir)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    wait_gone(pids)


def test_progress_bar_hides_node_chatter_but_not_warnings(procs: ProcessGroup, tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        python_path: [{json.dumps(str(TESTS))}]
        progress: {{topic: test/status}}
        nodes:
          - {{name: loud, cmd: {prog("loud")}}}
          - name: ticker
            node: launch_node_classes:ProgressTicker
            params: {{steps: 20, period_s: 0.1}}
            required: true
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir, "--progress")
    assert proc.wait(60) == 0, proc.output()
    out = proc.output()
    assert re.search(r"^progress +\d+% scanning  line \d+/20", out, re.M), out
    assert "[loud] WARNING this line is shown on screen" in out
    assert "[ticker] WARNING palpa.node.ticker: halfway there" in out
    assert "only goes to the log" not in out and "step 3 of 20" not in out and "started loud" not in out
    assert "launch ended: required node ticker ended (exit code 0); exit code 0" in out  # the summary stays
    assert "INFO this line only goes to the log" in (run_dir / "loud.log").read_text()
    assert "step 3 of 20" in (run_dir / "ticker.log").read_text()


def test_launch_ends_when_every_node_has_ended_and_exit_0_is_not_respawned(procs: ProcessGroup,
                                                                            tmp_path: Path) -> None:
    file = write(tmp_path, f"""
        nodes:
          - {{name: first, cmd: {prog("quit", "0", "0.2")}, respawn: true, respawn_delay: 0.1}}
          - {{name: second, cmd: {prog("quit", "0", "0.4")}}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    assert proc.wait(30) == 0, proc.output()
    out = proc.output()
    assert "stopping: every node has ended" in out
    assert len(starts(run_dir, "first")) == 1 and "respawning" not in out


def test_progress_lines_off_a_terminal_by_default_then_the_reported_nodes_results(procs: ProcessGroup,
                                                                                 tmp_path: Path) -> None:
    """Output to a pipe (as under `make demo | tee`): plain progress lines with no flag, and once the view ends,
    what the ``report`` node said under it (a map node's "map written: ...")."""
    file = write(tmp_path, f"""
        python_path: [{json.dumps(str(TESTS))}]
        progress: {{topic: test/status, report: [ticker]}}
        nodes:
          - name: ticker
            node: launch_node_classes:ProgressTicker
            params: {{steps: 20, period_s: 0.1}}
            required: true
    """)
    proc = launch(procs, file, tmp_path / "run")
    assert proc.wait(60) == 0, proc.output()
    out = proc.output()
    assert re.search(r"^progress +\d+% scanning  line \d+/20", out, re.M), out
    last_progress = max(m.end() for m in re.finditer(r"^progress .*$", out, re.M))
    assert out.index("[ticker] INFO palpa.node.ticker: step 20 of 20", last_progress) > last_progress
    assert "step 3 of 20" not in out  # only the last lines: the results, not the whole run
