"""How the launcher answers a node's end, once its process has been reaped.

A node that ended while being stopped is done: its outcome names the signal its stop needed, and an exit status
1-127 (it stopped when asked, but reports that its work failed) counts it failed. A node that ended by itself is
respawned when it failed and asks for it (palpa.launch.respawn: the delay and the retries); otherwise it is done,
and its end may end the launch: a required node's with its exit status, the recorder's when the file says
``record.required``. A node that was not required ends alone, the graph running on. What it said last is shown
when it failed with its lines kept off the screen. Split from palpa.launch.supervisor, which reaps the exits and
carries out the stop of the launch these ask for.
"""

from __future__ import annotations

import time

from palpa.launch.nodeproc import NodeProc
from palpa.launch.output import Screen
from palpa.launch.respawn import next_respawn
from palpa.launch.summary import exit_text

__all__ = ["StopRequest", "ended_by_itself", "ended_when_asked"]

StopRequest = tuple[str, int | None]
"""The launch's stop, asked for: its reason in words and its exit code (None: decided at the end)."""


def ended_when_asked(p: NodeProc, code: int, screen: Screen) -> None:
    """Node ``p``, which was being stopped, ended with ``code``: done, its outcome the signal its stop reached."""
    p.state = "done"
    p.outcome = {1: "stopped on SIGINT", 2: "needed SIGTERM", 3: "needed SIGKILL"}[p.stage]
    if 0 < code < 128:  # it stopped when asked, but reports that its work failed (an incomplete map);
        # 128+N is the signal's own exit status (stopped before its handler was in place), not a report
        p.failed, p.why = True, p.last_error()
        p.outcome += f", reporting failure ({exit_text(code)})"
    screen.say(f"{p.spec.name} {p.outcome} ({exit_text(code)})", "WARNING" if p.escalated else "INFO")


def ended_by_itself(p: NodeProc, code: int, screen: Screen, *, recorder: bool,
                    record_required: bool) -> StopRequest | None:
    """Node ``p`` ended on its own with ``code``: respawn it (if it failed and asks for it: ``p`` is then in
    backoff), end the launch (required; the recorder when ``record_required``: the stop returned), or carry on
    without it (the respawn policy: palpa.launch.respawn). ``recorder``: ``p`` is the launch's recorder."""
    spec, now = p.spec, time.monotonic()
    delay = next_respawn(p, code, now)
    retries = spec.respawn_max_retries
    if code != 0 and (spec.output == "log" or screen.view is not None):
        for line in p.tail:  # what it said last, since its lines were not on screen
            screen.show(f"[{spec.name}] {line}", loud=True)
    if delay is not None:
        p.state, p.respawn_at = "backoff", now + delay
        p.outcome = f"{exit_text(code)}; respawning"
        of = f"{p.failures}/{retries}" if retries >= 0 else f"{p.failures}"
        screen.say(f"{spec.name} ended ({exit_text(code)}); respawning in {delay:.2f} s (retry {of})", "WARNING")
        return None
    p.state = "done"
    p.failed = code != 0
    p.why = p.last_error() if p.failed else ""
    gave_up = spec.respawn and code != 0
    if gave_up:
        p.outcome = f"gave up after {p.failures} retries (last: {exit_text(code)})"
        screen.say(f"{spec.name}: giving up after {p.failures} retries (last: {exit_text(code)})", "ERROR")
    else:
        p.outcome = f"ended by itself ({exit_text(code)})"
    if spec.required:
        status = 128 - code if code < 0 else code
        return f"required node {spec.name} ended ({exit_text(code)})", status
    if recorder:
        screen.say(f"the recorder ended ({exit_text(code)}): the recording is incomplete", "ERROR")
        p.failed = True
        if record_required:
            return (f"the recorder ended ({exit_text(code)}); record.required: the rest of the run would go "
                    "unrecorded", 1)
    elif not gave_up:
        level = "INFO" if code == 0 else "WARNING"
        screen.say(f"{spec.name} ended ({exit_text(code)}); it is not required, the graph keeps running", level)
    return None
