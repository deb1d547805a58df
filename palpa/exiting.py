"""Ending a process without the interpreter's teardown, for the programs a launch waits on.

At exit CPython runs the exit handlers, then tears down every module and object: ~0.05-0.1 s for a process
that imported numpy, scipy and a graph's worth of node classes, all of it spent while a user (or a sweep of a
thousand runs) waits for the launch to end. :func:`exit_now` keeps the first part and skips the second.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import sys
import threading
from typing import NoReturn

__all__ = ["exit_now"]


def exit_now(code: int) -> NoReturn:
    """End the process as ``sys.exit(code)`` would, less the teardown: the exit handlers run (they flush the
    bus's last messages and close logging), then the standard streams are flushed. For a program whose files are
    all closed by then; with a thread of its own still running, the process exits the usual way, which waits
    for it."""
    if any(t is not threading.main_thread() and not t.daemon for t in threading.enumerate()):
        sys.exit(code)
    atexit._run_exitfuncs()  # what finalisation runs first
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)
