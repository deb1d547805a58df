"""The in-process tier's guard (tests/conftest.py) is real: an unmarked test cannot start a process or open a socket,
and a test marked ``system`` can."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest
import zmq

from tests.conftest import CrossesTier


def test_an_unmarked_test_is_stopped_at_a_process_a_socket_and_a_pty() -> None:
    with pytest.raises(CrossesTier, match="a process"):
        subprocess.run([sys.executable, "-c", "pass"], check=False)
    ctx = zmq.Context()
    try:
        with ctx.socket(zmq.PUB) as s, pytest.raises(CrossesTier, match="ipc://"):
            s.bind("ipc:///tmp/palpa-tier-check")
        with ctx.socket(zmq.PUB) as s:
            s.bind("inproc://tier-check")  # in-process ZeroMQ is allowed
    finally:
        ctx.term()
    with socket.socket() as s, pytest.raises(CrossesTier, match="socket"):
        s.connect(("127.0.0.1", 9))
    with pytest.raises(CrossesTier, match="pty"):
        os.openpty()


@pytest.mark.system
def test_a_system_test_may_start_a_process() -> None:
    assert subprocess.run([sys.executable, "-c", "pass"], check=False, timeout=60).returncode == 0
