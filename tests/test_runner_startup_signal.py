"""A node process given SIGINT or SIGTERM while its ``setup()`` is still running (connecting to a device, say): what
setup opened is closed, one line says so, and the exit code is 128 + the signal's number, with no traceback."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

import palpa
from tests.procs import ProcessGroup, palpa_cmd, short_ipc_base, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


class _Marker:
    """A resource whose close() leaves a file behind, so the test can see it was closed."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def close(self) -> None:
        self.path.write_text("closed", encoding="utf-8")


class SlowSetup(palpa.Node):
    """Opens a resource in setup(), says so in a file, then waits there (up to 60 s) as a device's connect might."""

    class Params(palpa.Params):
        dir: str = ""

    params: Params

    def setup(self) -> None:
        out = Path(self.params.dir)
        self.closing(_Marker(out / "closed"))
        (out / "in_setup").write_text(str(os.getpid()), encoding="utf-8")
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            time.sleep(0.01)


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_setup_closes_what_it_opened_and_exits_without_a_traceback(
        sig: int, code: int, procs: ProcessGroup, tmp_path: Path) -> None:
    p = procs.start(palpa_cmd("run", f"{__name__}:SlowSetup", "--name", "slow", "--bus", f"ipc://{short_ipc_base()}",
                              "-p", f"dir={tmp_path}"))
    wait_until(lambda: (tmp_path / "in_setup").exists() or p.popen.poll() is not None, timeout=30.0,
               what="the node to be in its setup")
    assert p.popen.poll() is None, p.output()
    p.signal(sig)
    assert p.wait(30.0) == code, p.output()
    out = p.output()
    assert "Traceback" not in out and f"{signal.Signals(sig).name} during start-up" in out, out
    assert (tmp_path / "closed").read_text(encoding="utf-8") == "closed"
