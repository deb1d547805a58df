"""Run a launch file as a process and listen on its bus (for acceptance tests of whole graphs)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import palpa
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from tests.procs import Proc, ProcessGroup, palpa_cmd, wait_until

REPO = Path(__file__).resolve().parent.parent


@contextmanager
def launched(procs: ProcessGroup, file: str, run_dir: Path, *args: str) -> Iterator[tuple[Proc, palpa.Node]]:
    """Start ``palpa launch FILE args`` with its run directory in ``run_dir``; yield the process and a node on
    its bus. The launch is interrupted (SIGINT) at the end if still running."""
    proc = procs.start(palpa_cmd("launch", str(REPO / file), "--run-dir", str(run_dir), "--no-progress", *args),
                       cwd=str(REPO))
    address_file = run_dir / "bus.address"
    wait_until(lambda: (address_file.exists() and address_file.read_text().endswith("\n"))
               or proc.popen.poll() is not None, 30, "the launcher's bus.address")
    assert address_file.exists(), proc.output()
    with palpa.Node(name="acceptance", bus=address_file.read_text().strip(), heartbeat_s=0) as node:
        yield proc, node
    if proc.popen.poll() is None:
        proc.stop(30)


def spin_until(node: palpa.Node, cond: Callable[[], bool], timeout: float, what: str, proc: Proc) -> None:
    """:func:`wait_until` spinning ``node``; a timeout shows the end of the launch's output."""
    try:
        wait_until(cond, timeout, what, step=lambda: node.spin_once(0.1))
    except AssertionError as exc:
        raise AssertionError(f"{exc}:\n{proc.output()[-4000:]}") from None


def wait_nodes_up(node: palpa.Node, names: set[str], timeout: float, proc: Proc) -> None:
    """Until every node in ``names`` has sent a heartbeat: the graph is up (a readiness signal, not a pause)."""
    heard: set[str] = set()
    node.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda hb: heard.add(hb.node))
    spin_until(node, lambda: names <= heard, timeout, f"heartbeats of {sorted(names)}", proc)
