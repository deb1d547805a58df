"""The sweep engine (tools.sweep) in this process, and the batch runner's keys and tables (issue 40). The same
engine on a Dask cluster: tests/test_sweep_cluster.py."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from tests.sweep_tasks import echo
from tools.evaluate import RunJob, RunSpec, main, run_key
from tools.evaluate_tables import read_tables, summarize, write_tables
from tools.sweep import Cluster, Store, Task, content_key, run_sweep, tree_digest

SERIAL = Cluster(serial=True)


def _tasks(tmp: Path, **extra: dict[str, Any]) -> list[Task]:
    """Four echo runs r0..r3; ``extra[name]`` adds to that run's argument (an error, an exception)."""
    return [Task(content_key({"n": i}), f"r{i}", echo, {"dir": str(tmp), "name": f"r{i}", "value": i,
                                                         **extra.get(f"r{i}", {})}) for i in range(4)]


def _ran(tmp: Path) -> list[str]:
    lines = (tmp / "ran").read_text().split() if (tmp / "ran").exists() else []
    (tmp / "ran").unlink(missing_ok=True)
    return lines


def test_a_sweep_run_again_runs_only_what_failed_or_is_missing(tmp_path: Path) -> None:
    store = Store(tmp_path / "results")
    first = run_sweep(_tasks(tmp_path, r1={"error": "launch failed (1)"}, r2={"raise": "boom"}), store, SERIAL,
                      say=lambda _: None)
    assert _ran(tmp_path) == ["r0", "r1", "r2", "r3"]
    assert [(r["name"], r["ok"], r["error"]) for r in first] == [
        ("r0", True, ""), ("r1", False, "launch failed (1)"), ("r2", False, "RuntimeError: boom"), ("r3", True, "")]
    assert [r["result"].get("value") for r in first] == [0, 1, None, 3]
    # the failed ones are kept (they are in the tables) but run again, as is a result deleted since
    store.path(first[3]["key"]).unlink()
    again = run_sweep(_tasks(tmp_path), store, SERIAL, say=lambda _: None)
    assert _ran(tmp_path) == ["r1", "r2", "r3"]
    assert all(r["ok"] for r in again) and [r["result"]["value"] for r in again] == [0, 1, 2, 3]
    assert sorted(p.name for p in store.root.iterdir()) == sorted(f"{t.key}.json" for t in _tasks(tmp_path))
    run_sweep(_tasks(tmp_path), store, SERIAL, say=lambda _: None)
    assert _ran(tmp_path) == []
    run_sweep(_tasks(tmp_path), store, SERIAL, rerun=True, say=lambda _: None)
    assert _ran(tmp_path) == ["r0", "r1", "r2", "r3"]


def test_a_result_that_cannot_be_read_is_made_again_not_trusted(tmp_path: Path) -> None:
    store = Store(tmp_path / "results")
    tasks = _tasks(tmp_path)
    run_sweep(tasks, store, SERIAL, say=lambda _: None)
    _ran(tmp_path)
    store.path(tasks[0].key).write_text('{"key": "')  # what a non-atomic write cut short would leave
    store.path(tasks[1].key).write_text(json.dumps({"key": "another", "ok": True}))  # not this key's
    run_sweep(tasks, store, SERIAL, say=lambda _: None)
    assert _ran(tmp_path) == ["r0", "r1"]
    assert [p.name for p in store.root.iterdir() if p.name.startswith(".")] == []  # no temporary file left


def test_two_runs_with_one_key_are_refused_before_anything_runs(tmp_path: Path) -> None:
    tasks = _tasks(tmp_path)
    with pytest.raises(ValueError, match="runs 'r0' and 'r9' have the same content key"):
        run_sweep([*tasks, Task(tasks[0].key, "r9", echo, {})], Store(tmp_path / "results"), SERIAL)
    assert _ran(tmp_path) == []


def test_the_run_key_follows_the_content_of_every_input(tmp_path: Path) -> None:
    launch, phantom, other = tmp_path / "l.yaml", tmp_path / "p.yaml", tmp_path / "q.yaml"
    launch.write_text("nodes: []\n")
    phantom.write_text("a: 1\n")
    other.write_text("a: 1\n")

    def key(ph: Path = phantom, seed: int = 0, code: str = "c", **args: Any) -> str:
        spec = RunSpec("r", ph, seed, args, {"phantom": str(ph), **args})
        return run_key(RunJob(launch, spec), code)

    base = key()
    assert key(other) == base  # the same bytes elsewhere: the same run
    assert len({base, key(seed=1), key(code="d"), key(spacing_mm=3.0)}) == 4
    phantom.write_text("a: 2\n")
    assert key() != base
    launch.write_text("nodes: [] # edited\n")
    assert key(other) != base
    # the code version sees an edit in any covered file
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text("x = 1\n")
    v1 = tree_digest(tmp_path, ["pkg"])
    (tmp_path / "pkg" / "m.py").write_text("x = 2\n")
    assert tree_digest(tmp_path, ["pkg"]) != v1


def test_tables_are_written_as_parquet_sorted_and_read_back_with_their_args(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    def run(rid: str, region: list[float], found: int, error: str = "") -> dict[str, Any]:
        scores = {} if error else {"true_inclusions": 2, "found": found, "false_positives": 0, "sensitivity": 0.5,
                                   "specificity": 0.99, "iou": 0.4, "mean_centroid_error_mm": 0.5, "scan_s": 10.0,
                                   "path_mm": 100.0, "probes": 50}
        return {"run": rid, "key": rid * 2, "region_mm": region, "exit_code": 1 if error else 0, "wall_s": 3.0,
                **scores, "error": error}

    rows = [run("b", [1.0, 2.0, 3.0, 4.0], 1), run("a", [0.0, 0.0, 5.0, 5.0], 2), run("c", [0.0, 0.0, 5.0, 5.0], 0,
                                                                                           "launch failed (1)")]
    incs = [{"run": "b", "inclusion": 1, "radius_mm": 3.0, "ratio": 2.0, "depth_mm": 1.0, "found": False,
             "centroid_error_mm": math.nan, "radius_error_mm": math.nan},
            {"run": "b", "inclusion": 0, "radius_mm": 5.0, "ratio": 4.0, "depth_mm": 1.0, "found": True,
             "centroid_error_mm": 0.5, "radius_error_mm": 0.1}]
    write_tables(tmp_path, {"runs": rows, "inclusions": incs, "detections": []}, ["region_mm"])
    tables, varied = read_tables(tmp_path)
    assert varied == ["region_mm"]
    assert list(tables["runs"]["run"]) == ["a", "b", "c"]
    assert list(tables["runs"]["region_mm"]) == [[0.0, 0.0, 5.0, 5.0], [1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 5.0, 5.0]]
    assert list(tables["inclusions"]["inclusion"]) == [0, 1] and tables["inclusions"]["radius_mm"].tolist() == [5, 3]
    assert len(tables["detections"]) == 0 and "x_mm" in tables["detections"].columns
    assert pd.read_csv(tmp_path / "runs.csv")["run"].tolist() == ["b", "a", "c"]  # today's CSV: as given
    live = summarize(rows, ["region_mm"])
    assert live[0].startswith("region_mm=[1.0, 2.0, 3.0, 4.0]: 1 of 1 runs scored; inclusions found 1/2")
    assert live[1].startswith("region_mm=[0.0, 0.0, 5.0, 5.0]: 1 of 2 runs scored; inclusions found 2/2")
    assert main(["--summary", str(tmp_path)]) == 0
    assert sorted(capsys.readouterr().out.splitlines()) == sorted(live)


def test_a_summary_of_a_folder_without_tables_says_which_file_is_missing(tmp_path: Path,
                                                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--summary", str(tmp_path)]) == 1
    assert f"--summary: {tmp_path / 'runs.parquet'}: no such table" in capsys.readouterr().err
