"""Where `make test`'s wall time goes across its xdist workers, and what another test order would give.

As a pytest plugin, it appends one JSON line per test (worker, node id, start and end wall time) to
``$SUITE_TIMELINE`` (default ``suite-timeline.jsonl``)::

    SUITE_TIMELINE=/tmp/t.jsonl PYTHONPATH=$PWD .venv/bin/python -m pytest -q -n 3 --dist loadgroup \\
        -p bench.suite_schedule

As a script, it reports each worker's end and the tail (last worker's end less the first's) of such a run, and
replays pytest-xdist 3.8's ``--dist loadgroup`` scheduler on its per-test durations for the collection order
as it is and with the ``--heavy`` tests (those of at least that many seconds in the run, outside any
xdist_group) moved first::

    PYTHONPATH=$PWD .venv/bin/python bench/suite_schedule.py /tmp/t.jsonl --heavy 7

The replay (LoadScopeScheduling as 3.8 has it): the xdist_group units largest first, then every other test in
collection order; one unit to each worker, then one more whenever a worker has at most two unfinished tests.
It ignores that tests slow each other down, so it compares orders on the same durations, nothing more.
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import time
from pathlib import Path
from typing import Any

_started: dict[str, float] = {}


def _out() -> Path:
    return Path(os.environ.get("SUITE_TIMELINE", "suite-timeline.jsonl"))


def _write(row: dict[str, Any]) -> None:
    with _out().open("a") as f:
        f.write(json.dumps(row) + "\n")


def pytest_sessionstart(session: Any) -> None:
    _write({"w": os.environ.get("PYTEST_XDIST_WORKER", "main"), "sessionstart": time.time()})


def pytest_runtest_logstart(nodeid: str, location: Any) -> None:
    _started[nodeid] = time.time()


def pytest_runtest_logfinish(nodeid: str, location: Any) -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    if worker != "main":  # the controller sees every test's report too
        _write({"w": worker, "id": nodeid, "s": _started.get(nodeid, time.time()), "e": time.time()})


def pytest_collection_finish(session: Any) -> None:
    if os.environ.get("PYTEST_XDIST_WORKER") in (None, "gw0"):
        groups = []
        for item in session.items:
            mark = item.get_closest_marker("xdist_group")
            groups.append({"id": item.nodeid, "group": (mark.args[0] if mark.args else mark.kwargs.get("name"))
                           if mark else None})
        _write({"order": groups})


def replay(order: list[dict[str, Any]], seconds: dict[str, float], workers: int) -> list[float]:
    """Each worker's end (s after its first test) under xdist 3.8's loadgroup scheduler."""
    units: dict[str, list[str]] = {}
    for row in order:
        units.setdefault(row["group"] or row["id"], []).append(row["id"])
    queue = [units[k] for k in sorted(units, key=lambda k: -len(units[k]))]  # stable, as xdist's sort
    todo: list[list[str]] = [[] for _ in range(workers)]

    def assign(w: int) -> None:
        if queue:
            todo[w].extend(queue.pop(0))

    for w in range(workers):
        assign(w)
    for w in range(workers):
        if len(todo[w]) <= 2:
            assign(w)
    events = [(seconds.get(todo[w][0], 0.0), w) for w in range(workers) if todo[w]]
    heapq.heapify(events)
    end = [0.0] * workers
    while events:
        t, w = heapq.heappop(events)
        todo[w].pop(0)
        end[w] = t
        if len(todo[w]) <= 2:
            assign(w)
        if todo[w]:
            heapq.heappush(events, (t + seconds.get(todo[w][0], 0.0), w))
    return end


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("timeline", type=Path)
    ap.add_argument("--heavy", type=float, default=7.0, help="seconds from which a test counts as heavy")
    opts = ap.parse_args()
    rows = [json.loads(line) for line in opts.timeline.read_text().splitlines() if line.strip()]
    tests = [r for r in rows if "id" in r]
    order = next(r["order"] for r in rows if "order" in r)
    t0 = min(r["sessionstart"] for r in rows if "sessionstart" in r)
    ends: dict[str, float] = {}
    for r in tests:
        ends[r["w"]] = max(ends.get(r["w"], 0.0), r["e"] - t0)
    seconds = {r["id"]: r["e"] - r["s"] for r in tests}
    workers = len(ends)
    print(f"run: {len(tests)} tests, {sum(seconds.values()):.0f} worker-s; first test at "
          f"{min(r['s'] for r in tests) - t0:.1f} s; worker ends " +
          ", ".join(f"{w} {e:.1f} s" for w, e in sorted(ends.items())) +
          f"; tail {max(ends.values()) - min(ends.values()):.1f} s")
    heavy = {r["id"] for r in order if seconds.get(r["id"], 0.0) >= opts.heavy and not r["group"]}
    for name, o in (("collection order", order),
                    (f"heavy first ({len(heavy)} tests >= {opts.heavy:g} s)",
                     sorted(order, key=lambda r: r["id"] not in heavy))):
        end = replay(o, seconds, workers)
        print(f"replayed, {name}: worker ends {', '.join(f'{e:.1f}' for e in end)} s; longest {max(end):.1f} s, "
              f"tail {max(end) - min(end):.1f} s")


if __name__ == "__main__":
    main()
