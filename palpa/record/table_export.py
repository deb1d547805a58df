"""``palpa bag export FILE --format csv|parquet``: a recording as tables for pandas, R, MATLAB, a spreadsheet.

Without ``--align``/``--rate``: one file per topic in the output directory (``probe/heights`` ->
``probe.heights.csv``), columns as :mod:`palpa.record.tables` says. With them: one table of several topics on one
time base (:func:`align`). CSV cells that are not scalars are written as JSON (lists, maps) or base64 (bytes);
Parquet keeps lists as list columns and stores the topic in the file's key-value metadata (``palpa.topic``).
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from palpa.atomic import written_beside
from palpa.record.format import BagError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["AlignSpec", "TableExport", "align", "export_tables", "table_file_name"]

Format = Literal["csv", "parquet"]
Method = Literal["nearest", "linear"]
TimeBase = Literal["publish", "log"]
_TIME_COLUMN = {"publish": "_publish_time_ns", "log": "_log_time_ns"}


@dataclass(frozen=True)
class AlignSpec:
    """How :func:`align` puts several topics on one time base.

    The rows are the messages of ``topic`` (``--align TOPIC``) or a grid every ``1/rate_hz`` seconds from the first
    to the last selected message (``--rate HZ``). Each other topic's column at a row's time ``t`` is, with
    ``nearest``, its sample closest to ``t``; with ``linear``, float columns are interpolated linearly between the
    samples just before and just after ``t`` (integers such as stamps, text and other cells take the nearest). Either way a cell is left
    empty when no sample of that topic lies within ``tolerance_s`` of ``t``: a row never borrows a value from far
    away. Times are the publishers' stamps (``time: publish``) or the recorder's receive times (``log``).
    """

    topic: str | None = None
    rate_hz: float | None = None
    method: Method = "nearest"
    tolerance_s: float = 0.1
    time: TimeBase = "publish"

    def describe(self) -> str:
        """One line for the output and the CLI: the rows, the method and the tolerance."""
        rows = f"rows at each {self.topic} message" if self.topic else f"rows every {1 / (self.rate_hz or 1):g} s"
        return (f"{rows}; other topics by {self.method} {'interpolation' if self.method == 'linear' else 'sample'}"
                f" within {self.tolerance_s:g} s ({self.time} times)")


def align(frames: dict[str, pd.DataFrame], spec: AlignSpec) -> pd.DataFrame:
    """One table of ``frames`` (:func:`palpa.record.tables.read`'s) on the time base ``spec`` describes. Columns:
    ``time_ns``, ``time_s`` (from the first row), then ``<topic>.<column>`` for every message column."""
    import numpy as np
    import pandas as pd

    if spec.tolerance_s < 0 or not math.isfinite(spec.tolerance_s):
        raise BagError(f"tolerance {spec.tolerance_s!r}: expected a finite number of seconds >= 0")
    tcol = _TIME_COLUMN[spec.time]
    frames = {t: f for t, f in frames.items() if len(f)}
    if not frames:
        raise BagError("no messages on the selected topics: nothing to align")
    if spec.topic is not None:
        if spec.topic not in frames:
            raise BagError(f"--align {spec.topic}: the recording has no message on it among the selected topics "
                           f"({', '.join(frames)})")
        grid = frames[spec.topic][tcol].to_numpy(dtype=np.int64)
    elif spec.rate_hz is not None and spec.rate_hz > 0 and math.isfinite(spec.rate_hz):
        lo = min(int(f[tcol].min()) for f in frames.values())
        hi = max(int(f[tcol].max()) for f in frames.values())
        step = 1e9 / spec.rate_hz
        n = int((hi - lo) // step) + 1
        if n > 50_000_000:
            raise BagError(f"--rate {spec.rate_hz:g} over {(hi - lo) / 1e9:.1f} s is {n} rows: choose a lower rate")
        grid = lo + np.round(np.arange(n) * step).astype(np.int64)
    else:
        raise BagError("give --align TOPIC or a positive --rate HZ")
    tol_ns = int(spec.tolerance_s * 1e9)
    out = pd.DataFrame({"time_ns": grid, "time_s": (grid - grid[0]) / 1e9 if len(grid) else grid})
    columns: dict[str, Any] = {}
    for topic, f in frames.items():
        f = f.sort_values(tcol, kind="stable")
        times = f[tcol].to_numpy(dtype=np.int64)
        nearest, near_ok = _nearest(times, grid, tol_ns)
        for col in f.columns:
            values = f[col]
            name = f"{topic}.{col}"
            if spec.method == "linear" and topic != spec.topic and _float(values):
                columns[name] = _linear(times, values.to_numpy(dtype=float), grid, near_ok)
            else:
                cell = values.iloc[nearest].reset_index(drop=True) if len(values) else values
                columns[name] = cell.where(pd.Series(near_ok), None) if not near_ok.all() else cell
    return pd.concat([out, pd.DataFrame(columns)], axis=1)


def _float(values: pd.Series) -> bool:
    """Interpolated columns: measurements (floats). Integers (stamps, counts, sequence numbers) take the nearest
    sample, exactly."""
    from pandas.api.types import is_float_dtype

    return bool(is_float_dtype(values))


def _nearest(times: Any, grid: Any, tol_ns: int) -> tuple[Any, Any]:
    """Index of each grid time's nearest sample, and whether that sample lies within ``tol_ns``."""
    import numpy as np

    right = np.clip(np.searchsorted(times, grid), 0, len(times) - 1)
    left = np.clip(right - 1, 0, len(times) - 1)
    pick = np.where(np.abs(times[left] - grid) <= np.abs(times[right] - grid), left, right)
    return pick, np.abs(times[pick] - grid) <= tol_ns


def _linear(times: Any, values: Any, grid: Any, near_ok: Any) -> Any:
    """Linear interpolation between the samples around each grid time; NaN beyond the samples' span and where no
    sample lies within the tolerance."""
    import numpy as np

    ok = ~np.isnan(values)
    if not ok.any():
        return np.full(len(grid), np.nan)
    t, v = times[ok].astype(float), values[ok]
    res = np.interp(grid.astype(float), t, v)
    res[(grid < t[0]) | (grid > t[-1]) | ~near_ok] = np.nan
    return res


# -- writing ---------------------------------------------------------------------------------------------------
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def table_file_name(topic: str, suffix: str, taken: set[str]) -> str:
    """A file name for ``topic``'s table: ``/`` becomes ``.``, other unsafe characters ``_``, clashes numbered."""
    stem = _UNSAFE.sub("_", topic.replace("/", ".")).strip(".") or "topic"
    name, n = f"{stem}.{suffix}", 1
    while name in taken:
        n += 1
        name = f"{stem}-{n}.{suffix}"
    taken.add(name)
    return name


def _csv_cell(value: Any) -> Any:
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode()
    if isinstance(value, list | dict | tuple):
        return json.dumps(value, default=lambda b: base64.b64encode(bytes(b)).decode())
    return value


def _write_csv(df: pd.DataFrame, path: Path) -> None:
    from pandas.api.types import is_object_dtype

    df = df.copy()
    for col in df.columns:
        if is_object_dtype(df[col]):
            df[col] = df[col].map(_csv_cell)
    df.to_csv(path, index=False)


def _write_parquet(df: pd.DataFrame, path: Path, metadata: dict[str, str]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = []
    for col in df.columns:
        try:
            arrays.append(pa.array(df[col], from_pandas=True))
        except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, OverflowError):
            # cells Arrow cannot type as one column (mixed kinds, ragged maps): JSON text, like the CSV
            arrays.append(pa.array(df[col].map(_csv_cell), from_pandas=True))
    table = pa.Table.from_arrays(arrays, names=[str(c) for c in df.columns])
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
    pq.write_table(table, path)


def _write(df: pd.DataFrame, path: Path, fmt: Format, metadata: dict[str, str]) -> None:
    if fmt == "csv":
        _write_csv(df, path)
    else:
        _write_parquet(df, path, metadata)


@dataclass
class TableExport:
    """What :func:`export_tables` wrote: the files, and rows per topic (or of the aligned table)."""

    output: Path
    files: list[Path] = field(default_factory=list)
    rows: dict[str, int] = field(default_factory=dict)
    method: str = ""
    aligned_rows: int = 0

    def text(self) -> str:
        """The summary line the CLI prints."""
        if self.method:
            return (f"wrote {self.aligned_rows} aligned rows of {len(self.rows)} topics to {self.output} "
                    f"({self.method})")
        return f"wrote {sum(self.rows.values())} rows of {len(self.rows)} topics to {len(self.files)} files in " \
               f"{self.output}"


def export_tables(frames: dict[str, pd.DataFrame], out: str | os.PathLike[str], fmt: Format, *,
                  spec: AlignSpec | None = None, overwrite: bool = False, source: str = "") -> TableExport:
    """Write ``frames`` as one file per topic into directory ``out``, or (``spec`` given) as one aligned table into
    file ``out``. Written beside the target and renamed into place, so a failure leaves no half-written output."""
    if fmt not in ("csv", "parquet"):
        raise BagError(f"--format {fmt!r}: expected csv or parquet")
    output = Path(out)
    if output.exists() and not overwrite:
        raise BagError(f"{output} already exists (use --force to overwrite)")
    if not frames:
        raise BagError("no messages on the selected topics: nothing to export")
    report = TableExport(output)
    with written_beside(output, over_directory=True) as tmp:
        if spec is not None:
            table = align(frames, spec)
            report.method = spec.describe()
            report.rows = {t: len(f) for t, f in frames.items()}
            report.aligned_rows = len(table)
            _write(table, tmp, fmt, {"palpa.source": source, "palpa.align": report.method})
            report.files = [output]
        else:
            tmp.mkdir(parents=True)
            taken: set[str] = set()
            for topic, df in frames.items():
                name = table_file_name(topic, fmt, taken)
                _write(df, tmp / name, fmt, {"palpa.topic": topic, "palpa.source": source})
                report.files.append(output / name)
                report.rows[topic] = len(df)
    return report

