"""Finding the running launch: every ``palpa launch`` binds a fresh bus, so it says where.

While a launch runs, ``palpa launch`` keeps a per-user "current bus" file (``current`` in the private socket
directory, palpa.net.address.private_dir; or ``$PALPA_CURRENT``) naming its bus, its pid and its run directory, and points ``runs/latest`` at the run
directory when that is in a ``runs`` folder. The CLI tools pick the bus in this order: ``--bus``, ``--run DIR`` (that
run's ``bus.address``), ``$PALPA_BUS``, the current launch (if its launcher is still alive), the default bus.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from palpa import env as palpa_env
from palpa.errors import BusError
from palpa.net.address import BusAddress, default_address, private_dir

__all__ = ["announce", "current_file", "find_bus", "read_current", "withdraw"]

CURRENT_ENV = palpa_env.CURRENT


def current_file() -> Path:
    """The per-user file that names the running launch's bus."""
    # in the private socket directory: a file another local user could make first would point tools at their bus
    return Path(palpa_env.get(CURRENT_ENV) or private_dir() / "current")


def announce(address: BusAddress, run_dir: Path) -> None:
    """Say that this process's launch, running in ``run_dir`` on ``address``, is the current one."""
    path = current_file()
    record = {"bus": str(address), "pid": os.getpid(), "run_dir": str(run_dir.resolve())}
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # readers never see half a file
    with contextlib.suppress(OSError):
        tmp.write_text(json.dumps(record) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    latest = run_dir.parent / "latest"
    if run_dir.parent.name != "runs" or run_dir.name == "latest" or (latest.exists() and not latest.is_symlink()):
        return  # only runs/latest (not /tmp/latest for --run-dir /tmp/x), and never over a real file
    link = run_dir.parent / f".latest.{os.getpid()}.tmp"
    with contextlib.suppress(OSError):
        link.unlink(missing_ok=True)
        link.symlink_to(run_dir.name)
        os.replace(link, latest)


def withdraw() -> None:
    """Remove the current-bus file if this process wrote it (a later launch may have taken it over)."""
    path = current_file()
    found = _read(path)
    if found is not None and found.get("pid") == os.getpid():
        with contextlib.suppress(OSError):
            path.unlink()


def _read(path: Path) -> dict[str, object] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _alive(pid: object) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read_current() -> tuple[str, str] | None:
    """(bus address, run directory) of the running launch, or None when no live launcher noted one."""
    data = _read(current_file())
    if data is None or not _alive(data.get("pid")):
        return None
    bus, run_dir = data.get("bus"), data.get("run_dir")
    if not isinstance(bus, str) or not isinstance(run_dir, str):
        return None
    return bus, run_dir


def find_bus(bus: str | None = None, run: Path | None = None) -> tuple[BusAddress, str]:
    """The bus a CLI tool should use, and where that choice came from (for messages such as "no nodes heard
    on ... (the launch in runs/x)")."""
    if bus:
        return BusAddress.parse(bus), "--bus"
    if run is not None:
        address_file = run / "bus.address"
        try:
            text = address_file.read_text(encoding="utf-8").strip()
        except OSError:
            raise BusError(f"--run {run}: no {address_file} (is it the run directory of a launch?)") from None
        return BusAddress.parse(text), f"the launch in {run}"
    env = palpa_env.get(palpa_env.BUS)
    if env:
        return BusAddress.parse(env), "$PALPA_BUS"
    current = read_current()
    if current is not None:
        return BusAddress.parse(current[0]), f"the running launch in {current[1]}"
    return BusAddress.parse(default_address()), "the default bus; no launch is running"
