"""Shared fixtures: short ipc paths, a bus per test (in-process or as a process), process cleanup."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from palpa.address import BusAddress
from palpa.bus import Bus
from tests.procs import ProcessGroup, bus_spec, palpa_cmd, short_ipc_base  # noqa: F401 (re-exported, see below)

# only for tests still written as top-level modules (test_scan_e2e.py on the in-flight issue-14 branches: `from procs
# import ...`, `from conftest import palpa_cmd`); remove with the re-exports once every test imports tests.procs
sys.path.append(str(Path(__file__).resolve().parent))

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

