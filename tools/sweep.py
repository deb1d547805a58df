"""A sweep: many independent runs on dask.distributed, each a task with a content key, each result kept once.

The engine of ``tools.evaluate`` and ``bench/adaptive.py``. A :class:`Task` names a picklable function, its
argument and a *content key*: a digest of everything that decides the result (the caller's inputs and the code
version, :func:`content_key`, :func:`tree_digest`). :func:`run_sweep` runs every task whose key has no successful
result in the :class:`Store` yet, on a local cluster (one single-threaded worker process per core) or on a running
scheduler (``tcp://HOST:8786``), prints the dashboard's address and, on a terminal, Dask's progress bar, and writes
each result under its key as it arrives (a temporary file renamed over: a result is there whole or not at all).

So a sweep cut short (Ctrl-C, a crashed client) and run again re-runs only what failed or is missing; a worker
killed mid-run is Dask's to recover (the scheduler gives its task to another worker, ``allowed-failures`` times),
and the result still lands once under its key. A failed run is a result too (``ok`` false, with its error), shown
in the tables and run again next time.

Generic (it knows nothing of palpation) but not in palpa/: palpa is the graph runtime, and a batch engine over a
compute cluster is no part of running a graph; this keeps dask out of every node's imports.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from palpa.atomic import write_beside

__all__ = ["Cluster", "Store", "Task", "content_key", "file_digest", "run_sweep", "tree_digest"]


@dataclass(frozen=True)
class Task:
    """One run of a sweep: ``fn(arg)`` returns a JSON-able dict, whose non-empty ``"error"`` marks it failed."""

    key: str
    """The content key (:func:`content_key`): equal keys are the same run."""
    name: str
    """A label for people (a run id): messages, the tables' ``run`` column."""
    fn: Callable[[Any], dict[str, Any]]
    """A module-level function, so a worker can import it."""
    arg: Any


def content_key(data: Any) -> str:
    """A digest of ``data`` (JSON-able; dict order does not matter): 32 hex characters."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def file_digest(path: Path) -> str:
    """A digest of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:32]


def tree_digest(root: Path, packages: Sequence[str], suffixes: Sequence[str] = (".py", ".yaml", ".npz")) -> str:
    """The code version: a digest of every file with one of ``suffixes`` under ``root/<package>`` (relative paths
    and bytes, in sorted order). Unlike a git commit it sees uncommitted edits, and needs no git on a worker."""
    h = hashlib.sha256()
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*")):
            if path.suffix in suffixes and path.is_file() and "__pycache__" not in path.parts:
                h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:32]


class Store:
    """Results by key, one JSON file each: ``ROOT/<key>.json`` = ``{"key", "name", "ok", "error", "result"}``."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, key: str) -> Path:
        """Where ``key``'s result is kept."""
        return self.root / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        """``key``'s record, or None when there is none (an unreadable file counts as none: the run is made
        again rather than trusted)."""
        try:
            record = json.loads(self.path(key).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return record if isinstance(record, dict) and record.get("key") == key else None

    def put(self, record: dict[str, Any]) -> None:
        """Write ``record`` under its key atomically: a reader sees the old file or the new one, never a part."""
        self.root.mkdir(parents=True, exist_ok=True)
        write_beside(self.path(record["key"]), json.dumps(record, default=str, allow_nan=True), per_writer=True)


def _record(task: Task, result: dict[str, Any]) -> dict[str, Any]:
    error = str(result.get("error") or "")
    return {"key": task.key, "name": task.name, "ok": not error, "error": error, "result": result}


def _call(fn: Callable[[Any], dict[str, Any]], arg: Any) -> dict[str, Any]:
    """Run on a worker: the task's own exception becomes a failed result (running it again would fail again);
    only a dying worker is left to Dask's retries."""
    try:
        return fn(arg)
    except Exception as exc:  # noqa: BLE001 - any failure of the run is reported, none kills the sweep
        return {"error": f"{type(exc).__name__}: {exc}"}


@dataclass(frozen=True)
class Cluster:
    """Where the runs go: ``scheduler`` (``tcp://HOST:8786``, a running cluster), else a local cluster of
    ``workers`` processes (default: one per core); ``serial`` runs them one by one in this process (no Dask: for
    a debugger, and as the reference the cluster's tables must equal)."""

    scheduler: str | None = None
    workers: int | None = None
    serial: bool = False


@contextlib.contextmanager
def _client(where: Cluster, say: Callable[[str], None]) -> Iterator[Any]:
    from dask.distributed import Client, LocalCluster

    # distributed's constructors are untyped: the ignores below say so, nothing more
    if where.scheduler:
        with Client(where.scheduler, timeout="30s") as client:  # type: ignore[no-untyped-call]
            say(f"scheduler {where.scheduler}, {len(client.scheduler_info()['workers'])} workers; "
                f"dashboard {client.dashboard_link}")
            yield client
        return
    n = where.workers or os.cpu_count() or 1
    # processes, one thread each: a run holds the GIL (or its own child process) for its whole length
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,  # type: ignore[no-untyped-call]
                           dashboard_address=":0")
    with cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        say(f"local cluster: {n} workers; dashboard {client.dashboard_link}")
        yield client


def run_sweep(tasks: Sequence[Task], store: Store, where: Cluster = Cluster(), *, rerun: bool = False,
              progress: bool | None = None, say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Run every task without a successful record in ``store`` (all of them with ``rerun``) and return every
    task's record, in the order of ``tasks``. ``progress``: Dask's bar (default: when stdout is a terminal);
    ``say``: where one-line messages go (default: stderr). Raises ValueError when two tasks share a key."""
    tell = say or (lambda line: print(line, file=sys.stderr, flush=True))
    seen: dict[str, str] = {}
    for t in tasks:
        if t.key in seen:
            raise ValueError(f"runs {seen[t.key]!r} and {t.name!r} have the same content key {t.key}: the same run "
                             "twice (give them different inputs, or drop one)")
        seen[t.key] = t.name
    done = {} if rerun else {t.key: r for t in tasks if (r := store.get(t.key)) is not None and r["ok"]}
    todo = [t for t in tasks if t.key not in done]
    if done:
        tell(f"{len(done)} of {len(tasks)} runs already done (their results are kept under {store.root}); "
             f"running {len(todo)}")
    if todo:
        for record in _execute(todo, where, tell, sys.stdout.isatty() if progress is None else progress):
            store.put(record)
            done[record["key"]] = record
            if not record["ok"]:
                tell(f"{record['name']}: {record['error']}")
    return [done[t.key] for t in tasks]


def _execute(todo: Sequence[Task], where: Cluster, tell: Callable[[str], None],
             bar: bool) -> Iterable[dict[str, Any]]:
    """Each task's record as it finishes."""
    if where.serial:
        for t in todo:
            yield _record(t, _call(t.fn, t.arg))
        return
    from dask.distributed import as_completed, progress

    with _client(where, tell) as client:
        by_key = {f"run-{t.key}": t for t in todo}
        futures = [client.submit(_call, t.fn, t.arg, key=k) for k, t in by_key.items()]
        shown = threading.Thread(target=progress, args=(futures,), daemon=True) if bar else None
        if shown:
            shown.start()
        # the futures are held to the end (a result is a few kB): Dask's bar waits for every key it was given
        for fut in as_completed(futures):  # type: ignore[no-untyped-call]
            task = by_key[fut.key]
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 - a task Dask gave up on (its workers kept dying): failed
                result = {"error": f"{type(exc).__name__}: {exc}"}
            yield _record(task, result)
        if shown:
            shown.join(10)
