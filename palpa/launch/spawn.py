"""How a launched node's process starts: its environment, and its start gate.

The environment is the entry's own (:meth:`~palpa.launch.plan.NodeSpec.child_env`: the bus, the run directory,
the python path, its parameters) with the key it signs its clock acks with, drawn from the run's master key; the
clock entry also gets the master key, to check them (palpa.timing.acksign). An entry started at a start gate
(palpa.startgate) inherits the gate's read end and waits there, importing its code, until the launcher lets it
through onto the bus or calls its start off. Split from palpa.launch.supervisor, which decides when a node starts
and watches it run.
"""

from __future__ import annotations

import os
from pathlib import Path

from palpa import env as palpa_env
from palpa.launch.compose import CLOCK_TARGET
from palpa.launch.plan import NodeSpec
from palpa.launch.process import Child
from palpa.net.address import BusAddress
from palpa.startgate import open_gate
from palpa.timing.acksign import node_key

__all__ = ["child_env", "start_child"]


def child_env(spec: NodeSpec, *, bus: BusAddress | None, run_dir: Path, python_path: list[str],
              clock_master: bytes) -> dict[str, str]:
    """The environment ``spec``'s process starts with (:meth:`NodeSpec.child_env`) and its key to sign its clock
    acks (from ``clock_master``, the run's master key); the clock entry also gets the master key, to check them."""
    env = spec.child_env(dict(os.environ), bus=bus, run_dir=run_dir, python_path=python_path)
    env[palpa_env.CLOCK_KEY] = node_key(clock_master, spec.name).hex()
    if spec.target == CLOCK_TARGET:
        env[palpa_env.CLOCK_MASTER_KEY] = clock_master.hex()
    return env


def start_child(argv: list[str], env: dict[str, str], *, gated: bool) -> tuple[Child, int]:
    """Start ``argv`` with ``env``; ``gated``: at a new start gate, whose write end is returned (-1 when not gated),
    for the caller to release. Raises OSError when the process cannot start (the gate is then closed)."""
    r = w = -1
    if gated:
        r, w = open_gate()
        env[palpa_env.START_GATE] = str(r)
    try:
        child = Child(argv, env, pass_fds=(r,) if gated else ())
    except OSError:
        if gated:
            os.close(w)
        raise
    finally:
        if gated:
            os.close(r)
    return child, w
