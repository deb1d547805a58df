"""Run functions for the sweep engine's tests (importable by a Dask worker): cheap stand-ins for a launch."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any


def echo(arg: dict[str, Any]) -> dict[str, Any]:
    """Its argument's ``value`` back (``error`` too, when given), and a line in ``DIR/ran`` per call."""
    with open(Path(arg["dir"]) / "ran", "a", encoding="utf-8") as f:
        f.write(f"{arg['name']}\n")
    if arg.get("raise"):
        raise RuntimeError(arg["raise"])
    return {"value": arg["value"], "error": arg.get("error", "")}


def held(arg: dict[str, Any]) -> dict[str, Any]:
    """Marks ``DIR/started-<name>-<pid>``; with ``hold``, then waits (at most 60 s) for ``DIR/go`` to exist, so a
    test can kill the worker process running it mid-run."""
    folder = Path(arg["dir"])
    (folder / f"started-{arg['name']}-{os.getpid()}").touch()
    deadline = time.monotonic() + 60
    while arg.get("hold") and not (folder / "go").exists():
        if time.monotonic() > deadline:
            return {"error": "never released"}
        time.sleep(0.01)
    return {"value": arg["name"], "error": ""}
