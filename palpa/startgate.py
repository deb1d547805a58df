"""The start gate: a child the launcher starts before its ``prepare`` commands have run, that imports its code
meanwhile and builds nothing until the launcher says go.

A composed simulation (``palpa launch --in-process``) spends ~0.3 s importing its node classes, while the launcher
spends ~0.2 s checking the same classes' parameters and ~0.2 s on the file's ``prepare`` step
(palpa.launch.prepare, started beside the checks): on two cores they run side by side instead of one after the
other.
The launcher starts such a child before its bus exists and passes it the read end of a pipe in
``PALPA_START_GATE``; ``go <bus address>`` and the end of the pipe let the child build its nodes on that bus, an
end without it (the launcher gave up: a check or a prepare step failed, or it died) makes the child leave having
built nothing.
"""

from __future__ import annotations

import contextlib
import os

from palpa import env as palpa_env

__all__ = ["GO", "open_gate", "release", "wait_for_go"]

GO = b"go"


def open_gate() -> tuple[int, int]:
    """A new gate: (read end for the child, inheritable; write end the launcher keeps, not inherited)."""
    r, w = os.pipe()
    os.set_inheritable(r, True)
    return r, w


def release(w: int, bus: str | None) -> None:
    """Let the child through onto ``bus`` or, with None, call its start off; either way the write end is closed."""
    try:
        if bus is not None:
            with contextlib.suppress(BrokenPipeError):  # the child is already gone: its exit tells the rest
                os.write(w, GO + b" " + bus.encode() + b"\n")
    finally:
        os.close(w)


def wait_for_go() -> bool:
    """In the child, its node classes imported: wait for the launcher's word and take the bus it names
    (``PALPA_BUS``). True at once without a gate (``PALPA_START_GATE`` unset); False if the launcher called the
    start off. The wait needs no deadline of its own: the launcher closes the pipe when it gives up, and its death
    closes it too."""
    fd_text = palpa_env.get(palpa_env.START_GATE)
    if not fd_text:
        return True
    fd = int(fd_text)
    word = b""
    try:
        while chunk := os.read(fd, 4096):
            word += chunk
    finally:
        os.close(fd)
        os.environ.pop(palpa_env.START_GATE, None)  # not for the child's own children
    verb, _, bus = word.decode(errors="replace").strip().partition(" ")
    if verb != GO.decode() or not bus:
        return False
    os.environ[palpa_env.BUS] = bus
    return True
