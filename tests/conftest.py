"""Shared fixtures: short ipc paths, a bus per test (in-process or as a process), process cleanup."""

from __future__ import annotations

import atexit
import contextlib
import functools
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

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
