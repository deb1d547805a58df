"""Sweeps on real Dask clusters (issue 40): a local cluster of two workers gives the serial run's tables, a worker
killed mid-run loses no run and duplicates none, and a cluster over network namespaces (a scheduler on one host,
workers on two others, the sweep started from a fourth) gives the same tables again.

The sweep is the real one: ``python -m tools.evaluate`` over four tiny rasters (one generated phantom, two seeds,
two line spacings, a 12 x 12 mm region; a few seconds each). The kill test runs a stand-in run function
(tests/sweep_tasks.py) through the real engine, so it can hold a run until the worker running it is killed.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest

from tests.netns import Hosts, why_no_netns
from tests.procs import REPO, ProcessGroup, wait_until
from tests.sweep_tasks import held
from tools.evaluate_tables import TABLES, WALL_CLOCK, read_tables
from tools.sweep import Cluster, Store, Task, content_key, run_sweep

pytestmark = pytest.mark.system
SWEEP = [str(REPO / "launch" / "scan_sim.yaml"), "--generate", "1", "--phantom-seed", "3", "--seeds", "0", "1",
         "--arg", "region_mm=[[8.0, 24.0, 20.0, 36.0]]", "--arg", "spacing_mm=4.0,6.0", "--arg", "touch_grid=2"]
"""Four runs: random_3 x seeds 0, 1 x spacing 4, 6 mm."""


def _evaluate(out: Path, *where: str, cmd: list[str] | None = None, env: dict[str, str] | None = None) -> str:
    """``python -m tools.evaluate`` of :data:`SWEEP` into ``out`` (``cmd``: a prefix, e.g. a namespace's);
    its output, after asserting exit 0."""
    argv = [*(cmd or []), sys.executable, "-m", "tools.evaluate", *SWEEP, "-o", str(out), *where]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=400, cwd=REPO, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout + proc.stderr


def _comparable(out: Path) -> dict[str, pd.DataFrame]:
    """The sweep's three tables without their wall-clock columns."""
    tables, _ = read_tables(out)
    return {n: tables[n].drop(columns=[c for c in WALL_CLOCK if c in tables[n].columns]) for n in TABLES}


def _assert_same_tables(a: Path, b: Path) -> None:
    ta, tb = _comparable(a), _comparable(b)
    assert len(ta["runs"]) == 4 and (ta["runs"]["error"] == "").all(), ta["runs"]
    assert ta["runs"]["probes"].min() > 100  # real scans, not empty rows that would compare equal too
    for name in TABLES:
        pd.testing.assert_frame_equal(ta[name], tb[name], check_exact=True)


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference: the sweep run one by one in the runner's own process (no Dask)."""
    out = tmp_path_factory.mktemp("serial")
    _evaluate(out, "--serial")
    return out


@pytest.mark.timeout(900)
def test_a_sweep_on_two_local_workers_gives_the_serial_tables_and_resumes(serial: Path, tmp_path: Path) -> None:
    out = tmp_path / "two"
    said = _evaluate(out, "--workers", "2")
    assert "local cluster: 2 workers; dashboard http://" in said
    _assert_same_tables(serial, out)
    # run again: nothing to do; a result lost: that run alone is made again, and the tables are the same
    assert "4 of 4 runs already done" in _evaluate(out, "--workers", "2")
    runs = pd.read_parquet(out / "runs.parquet")
    (out / "results" / f"{runs['key'][2]}.json").unlink()
    assert "3 of 4 runs already done (their results are kept under" in _evaluate(out, "--workers", "2")
    _assert_same_tables(serial, out)


@pytest.mark.timeout(300)
def test_a_worker_killed_mid_run_loses_no_run_and_duplicates_none(tmp_path: Path) -> None:
    """Run r1 holds until its worker process is killed (SIGKILL); Dask gives it to a worker again, the sweep
    ends with every run's result once."""
    tasks = [Task(content_key({"kill-test": i}), f"r{i}", held,
                  {"dir": str(tmp_path), "name": f"r{i}", "hold": i == 1}) for i in range(4)]
    killed: list[int] = []

    def kill_r1_mid_run() -> None:
        started = wait_until(lambda: next(tmp_path.glob("started-r1-*"), None), 120, "r1 to start on a worker")
        killed.append(int(started.name.rsplit("-", 1)[1]))
        os.kill(killed[0], signal.SIGKILL)
        (tmp_path / "go").touch()  # the run made again is not held

    killer = threading.Thread(target=kill_r1_mid_run, daemon=True)
    killer.start()
    store = Store(tmp_path / "results")
    records = run_sweep(tasks, store, Cluster(workers=2), progress=False)
    killer.join(10)
    assert killed, "r1 never started"
    assert [(r["name"], r["ok"], r["result"]["value"]) for r in records] == [(f"r{i}", True, f"r{i}")
                                                                             for i in range(4)]
    assert sorted(p.name for p in store.root.iterdir()) == sorted(f"{t.key}.json" for t in tasks)
    # r1 started twice, the second time in another process than the one killed
    r1 = sorted(int(p.name.rsplit("-", 1)[1]) for p in tmp_path.glob("started-r1-*"))
    assert len(r1) == 2 and killed[0] in r1, r1


_WHY = why_no_netns()


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    """Four hosts, deleted after the test's processes are gone (fixtures end in reverse order)."""
    with Hosts(4) as h:
        yield h


@pytest.mark.skipif(bool(_WHY), reason=_WHY or "ok")
@pytest.mark.timeout(900)
def test_a_sweep_over_hosts_gives_the_serial_tables(serial: Path, hosts: Hosts, procs: ProcessGroup,
                                                    tmp_path: Path) -> None:
    """A scheduler on host 1, a worker on each of hosts 2 and 3, the sweep started on host 4: network namespaces
    on a bridge of their own (tests/netns.py), the same tables as the serial run's."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    info = tmp_path / "scheduler.json"
    scheduler = procs.start(hosts.cmd(1, sys.executable, "-m", "distributed.cli.dask_scheduler", "--host",
                                      hosts.addr(1), "--port", "0", "--no-dashboard", "--scheduler-file",
                                      str(info)), env=env, cwd=str(REPO))

    def written() -> str | None:
        try:
            return str(json.loads(info.read_text())["address"])
        except (OSError, ValueError, KeyError):  # not yet, or half written
            return None

    address = wait_until(written, 60, "the scheduler's address")
    assert address.startswith(f"tcp://{hosts.addr(1)}:"), address
    workers = [procs.start(hosts.cmd(i, sys.executable, "-m", "distributed.cli.dask_worker", address, "--host",
                                     hosts.addr(i), "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
                                     "--local-directory", str(tmp_path / f"w{i}")), env=env, cwd=str(REPO))
               for i in (2, 3)]
    for w in workers:
        w.wait_for_output("Registered to:", 60)
    said = _evaluate(tmp_path / "hosts", "--scheduler", address, cmd=hosts.cmd(4), env=env)
    assert f"scheduler {address}, 2 workers" in said, said
    _assert_same_tables(serial, tmp_path / "hosts")
    for p in (*workers, scheduler):
        assert p.popen.poll() is None, p.output()
