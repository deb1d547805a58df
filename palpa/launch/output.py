"""Where the launcher's lines go.

Node lines: always to ``<run_dir>/<node>.log``; on screen as ``[node] line`` for ``output: screen`` nodes —
unless a progress bar is shown, when only "loud" lines (a WARNING/ERROR/CRITICAL level near the start, or a
traceback) reach the screen. Launcher messages: ``launch.log`` with millisecond timestamps, and ``[launch] ...``
on stderr (under a progress bar, only those above INFO).
"""

from __future__ import annotations

import os
import re
from datetime import datetime
from pathlib import Path
from typing import TextIO

from palpa.launch.progress import ProgressView

__all__ = ["Screen", "is_loud"]

_LOUD_RE = re.compile(r"^\W{0,3}(WARN|WARNING|ERROR|CRITICAL|FATAL)\b|^Traceback \(most recent call last\)")
_COLORS = ("36", "33", "35", "32", "34", "91", "96", "93", "95", "92")


def is_loud(line: str) -> bool:
    """True for a line that should reach the screen even under a progress bar."""
    return bool(_LOUD_RE.search(line))


class Screen:
    """The launcher's terminal (``out`` for node lines, ``err`` for its own) and its ``launch.log``."""

    def __init__(self, out: TextIO, err: TextIO) -> None:
        self.out = out
        self.err = err
        self.view: ProgressView | None = None
        self.launch_log: TextIO | None = None
        self._color = out.isatty() and not os.environ.get("NO_COLOR")

    def open_launch_log(self, path: Path) -> None:
        self.launch_log = open(path, "a", encoding="utf-8", buffering=1)  # noqa: SIM115 - closed in close()

    def color_for(self, index: int) -> str:
        """An ANSI color for the index-th node's prefix ('' when not on a terminal or NO_COLOR is set)."""
        return _COLORS[index % len(_COLORS)] if self._color else ""

    def node_line(self, name: str, color: str, output: str, text: str) -> bool:
        """Show one line of a node (the caller has already written it to the node's log); False if it was not
        shown (``output: log``, or a quiet line under the progress view)."""
        if output != "screen":
            return False
        loud = is_loud(text)
        if self.view is not None and not loud:
            return False
        prefix = f"\x1b[{color}m[{name}]\x1b[0m" if color else f"[{name}]"
        self.show(f"{prefix} {text}", loud=loud)
        return True

    def show(self, text: str, *, loud: bool, stream: TextIO | None = None) -> None:
        """Print a line: above the progress bar if there is one (loud lines only), else on ``stream``."""
        if self.view is not None:
            if loud:
                self.view.print(text)
            return
        s = stream or self.out
        try:
            s.write(text + "\n")
            s.flush()
        except (OSError, ValueError):  # a closed or broken terminal must not stop the supervision
            pass

    def say(self, text: str, level: str = "INFO") -> None:
        """A launcher message: to launch.log, and as ``[launch] text`` on stderr (INFO hidden under a bar)."""
        if self.launch_log is not None:
            try:
                stamp = datetime.now().strftime("%H:%M:%S.%f")[:-3]
                self.launch_log.write(f"{stamp} {level} {text}\n")
            except (OSError, ValueError):
                pass
        self.show(f"[launch] {text}", loud=level != "INFO", stream=self.err)

    def close_view(self) -> None:
        if self.view is not None:
            self.view.close()
            self.view = None

    def close(self) -> None:
        self.close_view()
        if self.launch_log is not None:
            self.launch_log.close()
            self.launch_log = None
