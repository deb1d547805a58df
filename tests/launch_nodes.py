"""Helper programs for the launch tests (standard library only, so they start fast):

    python launch_nodes.py stubborn      ignores SIGINT and SIGTERM
    python launch_nodes.py crash [CODE]  exits with CODE (default 3) at once
    python launch_nodes.py steady        prints "tick N" every 0.1 s until SIGINT/SIGTERM, then exits 0
    python launch_nodes.py quit CODE S   prints a line, exits with CODE after S seconds
    python launch_nodes.py crash_once F  exits 3 if file F does not exist (creating it), else is steady
    python launch_nodes.py fail_on_stop  is steady, but exits 4 when stopped
    python launch_nodes.py parent        starts a grandchild (steady) in the same process group, then is steady
    python launch_nodes.py env           prints its PALPA_* environment as one JSON line, then is steady
    python launch_nodes.py loud          prints an INFO and a WARNING line, then is steady

Every program ends by itself after 60 s, so a broken test cannot leave it running for long.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from types import FrameType

LIFETIME_S = 60.0
_stop = False


def _on_stop(signum: int, frame: FrameType | None) -> None:
    global _stop
    _stop = True


def steady() -> int:
    signal.signal(signal.SIGINT, _on_stop)
    signal.signal(signal.SIGTERM, _on_stop)
    print(f"steady pid {os.getpid()}", flush=True)
    end = time.monotonic() + LIFETIME_S
    n = 0
    while not _stop and time.monotonic() < end:
        n += 1
        print(f"tick {n}", flush=True)
        time.sleep(0.1)
    print("steady: stopping cleanly", flush=True)
    return 0


def stubborn() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    print(f"stubborn ready pid {os.getpid()}", flush=True)
    end = time.monotonic() + LIFETIME_S
    while time.monotonic() < end:
        time.sleep(0.05)
    return 0


def main(argv: list[str]) -> int:
    kind = argv[0] if argv else ""
    if kind == "steady":
        return steady()
    if kind == "stubborn":
        return stubborn()
    if kind == "crash":
        print("crash: starting and failing at once", flush=True)
        return int(argv[1]) if len(argv) > 1 else 3
    if kind == "quit":
        print(f"quit: exiting {argv[1]} in {argv[2]} s", flush=True)
        time.sleep(float(argv[2]))
        return int(argv[1])
    if kind == "crash_once":  # fails the first time (no FILE yet), then runs steady
        if not os.path.exists(argv[1]):
            open(argv[1], "w").close()
            print("crash_once: failing this first time", flush=True)
            return 3
        return steady()
    if kind == "fail_on_stop":  # steady, but reports failure (exit 4) when asked to stop, and why
        steady()
        print("ERROR palpa.node.mapper: the map is INCOMPLETE and may be wrong: stopped at 20 %", flush=True)
        return 4
    if kind == "parent":
        grandchild = subprocess.Popen([sys.executable, __file__, "steady"], stdout=subprocess.DEVNULL)
        print(f"parent pid {os.getpid()} grandchild pid {grandchild.pid}", flush=True)
        return steady()
    if kind == "env":
        keys = sorted(k for k in os.environ if k.startswith("PALPA_") or k in ("PYTHONUNBUFFERED", "EXTRA"))
        print("env " + json.dumps({k: os.environ[k] for k in keys}), flush=True)
        return steady()
    if kind == "loud":
        print("INFO this line only goes to the log", flush=True)
        print("WARNING this line is shown on screen", flush=True)
        return steady()
    print(f"unknown program {kind!r}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
