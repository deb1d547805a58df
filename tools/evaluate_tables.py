"""The batch runner's tables (``tools.evaluate``): runs, inclusions and detections, as Parquet beside CSV/JSON.

``OUT/runs.parquet``: one row per run (``run``, ``key``, ``phantom``, ``seed``, the varied args, ``exit_code``,
``wall_s``, ``cpu_s``, ``error`` and the scores: counts, ``sensitivity``, ``specificity``, ``iou``, ``*_mm``
errors and lengths, ``*_s`` durations, ``probes``); ``OUT/inclusions.parquet``: one per true inclusion per run (``radius_mm``, ``ratio`` = its
stiffness over the background's, ``depth_mm``, ``found``, errors in mm); ``OUT/detections.parquet``: one per
detection per run (``x_mm``, ``y_mm``, ``radius_mm``, ``contrast``, ``inclusion``: the true inclusion it matched,
-1 for a false positive). Rows are sorted by run (and index), so a sweep gives the same tables however many
workers ran it; only :data:`WALL_CLOCK` columns differ between two identical sweeps. Units are in the column names.
A varied arg whose values are lists is stored as JSON text (and read back as lists by :func:`read_tables`).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from palpa.atomic import write_beside, written_beside

__all__ = ["TABLES", "WALL_CLOCK", "read_tables", "summarize", "write_tables"]

TABLES = ("runs", "inclusions", "detections")
WALL_CLOCK = ("wall_s", "cpu_s")
"""Columns measured on the machine (wall and CPU seconds): they differ between two runs of the same sweep."""
_SORT = {"runs": ["run"], "inclusions": ["run", "inclusion"], "detections": ["run", "detection"]}
_COLUMNS = {"inclusions": ["run", "inclusion", "radius_mm", "ratio", "depth_mm", "found", "centroid_error_mm",
                           "radius_error_mm"],
            "detections": ["run", "detection", "x_mm", "y_mm", "radius_mm", "contrast", "inclusion"]}
"""The columns of a table with no rows (the runs table's depend on the varied args: it has a row per run)."""
_META = b"palpa.evaluate"


def _frame(rows: list[dict[str, Any]], name: str) -> tuple[Any, list[str]]:
    """A DataFrame of ``rows`` sorted by :data:`_SORT`, with columns of lists/dicts as JSON text (their names)."""
    import pandas as pd

    df = pd.DataFrame(rows) if rows else pd.DataFrame(columns=_COLUMNS.get(name, _SORT[name]))
    encoded = []
    for col in df.columns:
        if df[col].dtype == object and any(isinstance(v, list | dict | tuple) for v in df[col]):
            df[col] = [None if v is None else json.dumps(v) for v in df[col]]
            encoded.append(str(col))
    keys = [k for k in _SORT[name] if k in df.columns]
    if keys and len(df):
        df = df.sort_values(keys, kind="stable").reset_index(drop=True)
    return df, encoded


def write_tables(out: Path, tables: dict[str, list[dict[str, Any]]], varied: Sequence[str]) -> None:
    """``runs``, ``inclusions`` and ``detections`` as ``OUT/<name>.parquet`` and ``.csv``, and ``runs.json``
    (today's readers); each file written whole under a temporary name, then renamed over."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = tables["runs"]
    write_beside(out / "runs.json", json.dumps(rows, indent=1, default=str), per_writer=True)
    for name in TABLES:
        df, encoded = _frame(tables[name], name)
        table = pa.Table.from_pandas(df, preserve_index=False)
        meta = {**(table.schema.metadata or {}), _META: json.dumps({"varied": list(varied), "json": encoded})}
        tagged = table.replace_schema_metadata(meta)
        with written_beside(out / f"{name}.parquet", per_writer=True) as tmp:
            pq.write_table(tagged, tmp)
        with written_beside(out / f"{name}.csv", per_writer=True) as tmp:
            _write_csv(tmp, tables[name])


def _write_csv(path: Path, table: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in table:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows({k: json.dumps(v) if isinstance(v, list | dict) else v for k, v in r.items()} for r in table)


def read_tables(out: Path) -> tuple[dict[str, Any], list[str]]:
    """The three tables of a finished sweep in ``out`` as pandas DataFrames, and the names of its varied args
    (raises FileNotFoundError naming the missing file)."""
    import pyarrow.parquet as pq

    tables: dict[str, Any] = {}
    varied: list[str] = []
    for name in TABLES:
        path = out / f"{name}.parquet"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such table (is {out} the -o folder of a finished sweep?)")
        table = pq.read_table(path)
        meta = json.loads((table.schema.metadata or {}).get(_META, b"{}"))
        df = table.to_pandas()
        for col in meta.get("json", []):
            df[col] = [None if v is None else json.loads(v) for v in df[col]]
        tables[name] = df
        varied = varied or list(meta.get("varied", []))
    return tables, varied


def summarize(rows: list[dict[str, Any]], varied: Sequence[str]) -> list[str]:
    """Per arg combination: runs (failed), inclusions found of all, false positives, mean sensitivity,
    specificity and centroid error, mean scan time."""
    lines = []
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(json.dumps(r.get(k)) for k in varied), []).append(r)
    for key, group in groups.items():
        ok = [r for r in group if not r.get("error")]
        label = ", ".join(f"{k}={v}" for k, v in zip(varied, key, strict=True)) or "all runs"

        def mean(name: str, rs: list[dict[str, Any]] = ok) -> float:
            vals = [float(r[name]) for r in rs if isinstance(r.get(name), int | float) and math.isfinite(r[name])]
            return float(np.mean(vals)) if vals else math.nan

        found = sum(int(r["found"]) for r in ok)
        total = sum(int(r["true_inclusions"]) for r in ok)
        errors = [r["mean_centroid_error_mm"] for r in ok if math.isfinite(r["mean_centroid_error_mm"])]
        lines.append(
            f"{label}: {len(ok)} of {len(group)} runs scored; inclusions found {found}/{total}"
            + (f" ({100 * found / total:.0f} %)" if total else "; no inclusions in these phantoms")
            + f"; false positives {sum(int(r['false_positives']) for r in ok)}"
            f"; sensitivity {mean('sensitivity'):.2f}, specificity {mean('specificity'):.3f}, IoU {mean('iou'):.2f}"
            f"; centroid error {np.mean(errors) if errors else math.nan:.2f} mm"
            f"; scan {mean('scan_s'):.0f} s, path {mean('path_mm'):.0f} mm, {mean('probes'):.0f} probe samples")
    return lines
