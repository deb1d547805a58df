"""A progress bar for a launched graph, fed by any message with a ``progress`` field (0..1).

Optional fields: ``state`` and ``message`` (text), ``eta_s`` (seconds), ``line`` and ``lines`` (counts). The
launcher decodes the payload as plain msgpack, so the message type need not be importable here and the runtime
keeps knowing nothing about what is being scanned. On a terminal the bar is drawn with rich; otherwise (when
forced with ``--progress``) a plain line is printed whenever the percentage moves by 5 or the state changes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, TextIO

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TaskID, TaskProgressColumn, TextColumn

from palpa.errors import DecodeError
from palpa.net.wire import decode_any

__all__ = ["ProgressView", "progress_fields"]


def progress_fields(payload: bytes) -> dict[str, Any] | None:
    """The progress fields of a msgpack payload, or None if it is not a map with a numeric ``progress``."""
    try:
        data = decode_any(payload)
    except DecodeError:
        return None
    if not isinstance(data, dict):
        return None
    value = data.get("progress")
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        return None
    out: dict[str, Any] = {"progress": min(1.0, max(0.0, float(value)))}
    for key, kinds in (("state", str), ("message", str), ("eta_s", (int, float)), ("line", int), ("lines", int)):
        v = data.get(key)
        if isinstance(v, kinds) and not isinstance(v, bool):
            out[key] = v
    return out


def _clock(seconds: float) -> str:
    return f"{int(seconds) // 60}:{int(seconds) % 60:02d}"


def _detail(fields: Mapping[str, Any], wall_eta_s: float | None = None) -> str:
    """The text after the bar. ``eta_s`` is on the publisher's clock (simulated time in a simulation, which runs
    faster or slower than the wall); ``wall_eta_s``, when known, is the wall time left at the pace seen so far, and
    then both are shown, labelled."""
    parts = []
    if "line" in fields:
        parts.append(f"line {fields['line']}" + (f"/{fields['lines']}" if "lines" in fields else ""))
    raw = fields.get("eta_s")
    eta = float(raw) if isinstance(raw, int | float) and math.isfinite(raw) and raw >= 0 else None
    if wall_eta_s is not None and math.isfinite(wall_eta_s):
        parts.append(f"eta {_clock(wall_eta_s)} wall" + (f" ({_clock(eta)} on the scan's clock)" if eta is not None
                                                          else ""))
    elif eta is not None:
        parts.append(f"eta {_clock(eta)}")
    if fields.get("message"):
        parts.append(str(fields["message"]))
    return "  ".join(parts)


class ProgressView:
    """Draws the bar; :meth:`print` puts other lines (warnings, the summary) above it."""

    def __init__(self, topic: str, stream: TextIO, *, terminal: bool | None = None) -> None:
        self.topic = topic
        self._stream = stream
        self._terminal = stream.isatty() if terminal is None else terminal
        self._last_pct = -100
        self._last_state: Any = None
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self.updates = 0
        self._first: tuple[float, int] | None = None  # (progress, wall ns) of the first update under way
        if self._terminal:
            console = Console(file=stream)
            self._progress = Progress(
                TextColumn("[bold]{task.fields[state]}"), BarColumn(), TaskProgressColumn(),
                TextColumn("{task.fields[detail]}"), console=console, transient=False,
            )
            self._task = self._progress.add_task("scan", total=1.0, state="waiting", detail=topic)
            self._progress.start()

    def update(self, fields: Mapping[str, Any], wall_ns: int | None = None) -> None:
        """Show new progress (``fields`` as returned by :func:`progress_fields`). ``wall_ns``, when the caller
        knows it (the message's receive time), paces a wall-time ETA from the progress made since the first
        update that had any."""
        self.updates += 1
        value = float(fields["progress"])
        state = str(fields.get("state", ""))
        wall_eta = self._wall_eta(value, wall_ns)
        if self._progress is not None and self._task is not None:
            self._progress.update(self._task, completed=value, state=escape(state or "running"),
                                  detail=escape(_detail(fields, wall_eta)))
            return
        pct = int(value * 100)
        if abs(pct - self._last_pct) >= 5 or state != self._last_state or (pct == 100 and self._last_pct != 100):
            self._last_pct, self._last_state = pct, state
            detail = _detail(fields, wall_eta)
            self.print(f"progress {pct:3d}%" + (f" {state}" if state else "") + (f"  {detail}" if detail else ""))

    def _wall_eta(self, value: float, wall_ns: int | None) -> float | None:
        """Wall seconds left at the pace since the first update under way (None until 2 % more are done)."""
        if wall_ns is None or value <= 0.0:
            return None
        if self._first is None:
            self._first = (value, wall_ns)
            return None
        done, elapsed = value - self._first[0], (wall_ns - self._first[1]) / 1e9
        if done < 0.02 or elapsed <= 0:
            return None
        return max(0.0, (1.0 - value) * elapsed / done)

    def print(self, text: str) -> None:
        """Print a line above the bar (or plainly, without one)."""
        if self._progress is not None:
            self._progress.console.print(text, markup=False, highlight=False, soft_wrap=True)
        else:
            try:
                self._stream.write(text + "\n")
                self._stream.flush()
            except (OSError, ValueError):
                pass

    def close(self) -> None:
        """Stop drawing (the bar stays on screen as last shown)."""
        if self._progress is not None:
            self._progress.stop()
            self._progress = None
