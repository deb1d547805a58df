"""How a launch's nodes ended, in words and in its exit code.

:func:`exit_text` words a process's return code; :func:`report_hidden` shows, once the progress bar is gone, what
the ``progress: {report: [...]}`` nodes said under it (where the results went); :func:`summarize` prints the
summary table (a ``!`` on each node that failed or needed SIGTERM or SIGKILL) and decides the exit code: the
required node's when one ended the launch, else 1 when a node failed or was respawned mid-run (a respawn recovers
the graph, not what the node held or missed while down), else 0. Split from palpa.launch.supervisor, which keeps
the outcomes these read.
"""

from __future__ import annotations

import signal
from collections.abc import Collection, Sequence
from pathlib import Path

from palpa.launch.nodeproc import NodeProc
from palpa.launch.output import Screen

__all__ = ["exit_text", "report_hidden", "summarize"]


def exit_text(code: int) -> str:
    """'exit code 3' or 'killed by SIGKILL' for a Popen return code."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def report_hidden(screen: Screen, procs: Sequence[NodeProc], report: Collection[str]) -> None:
    """After the progress view: what the ``report`` nodes said under it (where the results went). An entry
    ``PROC:NODE`` names a node composed into process PROC (``--in-process``): of PROC's lines, those NODE's logger
    wrote (``palpa.node.NODE:``)."""
    for p in procs:
        members = [r.partition(":")[2] for r in report if r.partition(":")[0] == p.spec.name]
        if not members:
            continue
        loggers = tuple(f"palpa.node.{m}:" for m in members if m)
        for line in p.hidden:
            if not loggers or any(lg in line for lg in loggers):
                screen.show(f"[{p.spec.name}] {line}", loud=False)


def summarize(screen: Screen, procs: Sequence[NodeProc], run_dir: Path, reason: str, code: int | None) -> int:
    """Print the summary and the launch's end, close the screen; returns the launch's exit code (``code``: the
    one asked for when the launch was stopped, None if none was)."""
    code = code if code is not None else 0
    failed = [p.spec.name + (f" ({p.why})" if p.why else "") for p in procs if p.failed]
    restarted = [p.spec.name for p in procs if p.starts > 1 and not p.failed]
    reason = reason or "ended"
    if code == 0 and failed:
        code = 1
        reason += f"; failed: {', '.join(failed)}"
    if restarted:  # a respawn recovers the graph, not what the node held or missed while down
        code = code or 1
        reason += f"; restarted mid-run (data lost while down): {', '.join(restarted)}"
    width = max((len(p.spec.name) for p in procs), default=4)
    lines = [f"summary (logs in {run_dir}):"]
    for p in procs:
        mark = "!" if (p.failed or p.escalated) else " "
        starts = f"  (started {p.starts} times)" if p.starts > 1 else ""
        lines.append(f" {mark} {p.spec.name:<{width}}  {p.outcome}{starts}")
    lines.append(f"launch ended: {reason}; exit code {code}")
    for line in lines:
        screen.say(line, "WARNING" if line.startswith(" !") else "NOTICE")
    screen.close()
    return code
