"""Shared fixtures: short ipc paths, a bus per test (in-process or as a process), process cleanup."""

from __future__ import annotations

import atexit
import contextlib
import functools
import multiprocessing.process
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from tests.procs import ProcessGroup, bus_spec

# launches started by tests note their bus here, not in the user's own current-bus file (palpa.current)
os.environ["PALPA_CURRENT"] = f"/tmp/pt-current-{os.getpid()}"


@pytest.fixture(params=["ipc", "tcp"])
def transport(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def bus(transport: str) -> Iterator[BusAddress]:
    """An in-process bus over ipc and over tcp (the test runs once for each)."""
    with Bus(bus_spec(transport), latched_topics=["graph/latched"]) as b:
        assert b.address is not None
        yield b.address


@pytest.fixture
def ipc_bus() -> Iterator[BusAddress]:
    with Bus(bus_spec("ipc")) as b:
        assert b.address is not None
        yield b.address


@pytest.fixture
def stack() -> Iterator[contextlib.ExitStack]:
    """Context managers entered through this (emulators, drivers) are all exited at the end of the test."""
    with contextlib.ExitStack() as s:
        yield s


@pytest.fixture
def procs() -> Iterator[ProcessGroup]:
    """Start processes through this; all are killed (and their output dumped on failure) at the end."""
    group = ProcessGroup()
    try:
        yield group
    finally:
        group.cleanup()


@pytest.fixture
def env_for() -> object:
    def make(address: BusAddress, **extra: str) -> dict[str, str]:
        env = dict(os.environ)
        env["PALPA_BUS"] = str(address)
        env["PYTHONUNBUFFERED"] = "1"
        env.update(extra)
        return env

    return make



@functools.lru_cache(maxsize=1)
def airfloat_calibration() -> Path:
    """The simulated air-float probe (device 0) calibrated on the bench once per session, as `make demo` and a user
    on the rig do before scanning (tools.calibrate_airfloat: force sensor + the two reference samples)."""
    from models.calibration_airfloat import save_calibration
    from tools.calibrate_airfloat import DEFAULT_REFERENCES, Reference, calibrate

    folder = tempfile.mkdtemp(prefix="palpa-cal-")
    atexit.register(shutil.rmtree, folder, True)  # one per worker process, gone with it
    path = Path(folder) / "calibration.yaml"
    save_calibration(path, calibrate(0, [Reference.parse(t) for t in DEFAULT_REFERENCES]))
    return path


@pytest.fixture
def calibration() -> Path:
    """See :func:`airfloat_calibration`."""
    return airfloat_calibration()


# --- the two tiers --------------------------------------------------------------------------------------------------
# `make test` runs the in-process tier (pure, harness, composition); `make test-system` the tests marked `system`, which
# cross a process, a socket, ur_rtde, a pty or a network namespace. An unmarked test that tries one of those is stopped
# here with a message naming the call, so the fast tier cannot grow a slow, load-sensitive test by accident.


class CrossesTier(AssertionError):
    """An in-process-tier test reached for a process, a real socket or a pty: mark it ``system``."""


def _refuse(what: str) -> None:
    raise CrossesTier(f"{what} in the in-process tier: mark the test `pytest.mark.system` (make test-system)")


def _guarded_zmq(real: Any) -> Any:
    def call(self: Any, addr: Any, *args: Any, **kwargs: Any) -> Any:
        text = addr.decode() if isinstance(addr, bytes) else str(addr)
        if not text.startswith("inproc://"):
            _refuse(f"a ZeroMQ socket on {text}")
        return real(self, addr, *args, **kwargs)

    return call


def _refused_socket(self: socket.socket, address: Any, *args: Any) -> None:
    _refuse(f"a {self.family.name} socket on {address}")

@pytest.fixture(autouse=True)
def _in_process_tier(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    if request.node.get_closest_marker("system") is not None:
        return
    import zmq

    monkeypatch.setattr(zmq.Socket, "bind", _guarded_zmq(zmq.Socket.bind))
    monkeypatch.setattr(zmq.Socket, "connect", _guarded_zmq(zmq.Socket.connect))
    monkeypatch.setattr(socket.socket, "bind", _refused_socket)
    monkeypatch.setattr(socket.socket, "connect", _refused_socket)
    monkeypatch.setattr(subprocess.Popen, "__init__", lambda *a, **k: _refuse(f"a process {a[1] if len(a) > 1 else ''}"))
    monkeypatch.setattr(os, "openpty", lambda: _refuse("a pty"))
    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", lambda self: _refuse(f"a process {self.name}"))
