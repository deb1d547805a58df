"""Finding the running launches: every ``palpa launch`` binds a fresh bus, so it says where, and a tool never guesses.

While a launch runs, ``palpa launch`` keeps an entry in this user's directory of running launches (``launches`` in
the private socket directory, palpa.net.address.private_dir; or ``$PALPA_CURRENT``): one JSON file per launch naming its
bus, its launcher's pid (and that process's start time, so a reused pid is not believed) and its run directory;
it points ``runs/latest`` at the run directory when that is in a ``runs`` folder. An entry whose launcher is gone
(killed, it could not withdraw) is stale: it is removed when read and never counts.

The CLI tools pick the bus in this order: ``--bus``, ``--run RUN`` (that run directory's ``bus.address``, or the
running launch whose run directory is named RUN), ``$PALPA_BUS``, the one running launch, the default bus when no
launch runs. With more than one launch running a tool does not guess (an e-stop sent to the wrong graph): it names
them and asks for ``--run`` or ``--bus``.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
from dataclasses import dataclass
from pathlib import Path

from palpa import env as palpa_env
from palpa.atomic import write_beside, written_beside
from palpa.errors import BusError
from palpa.net.address import BusAddress, default_address, private_dir

__all__ = ["RunningLaunch", "announce", "find_bus", "launches_dir", "running_launches", "withdraw"]

CURRENT_ENV = palpa_env.CURRENT
_entries = itertools.count(1)


@dataclass(frozen=True)
class RunningLaunch:
    """A launch running on this machine for this user: its bus, its launcher's pid and its run directory."""

    bus: str
    pid: int
    run_dir: str


def launches_dir() -> Path:
    """The per-user directory of running launches (one entry per launch)."""
    # in the private socket directory: an entry another local user could write would point tools at their bus
    return Path(palpa_env.get(CURRENT_ENV) or private_dir() / "launches")


def announce(address: BusAddress, run_dir: Path) -> Path:
    """Say that a launch runs in ``run_dir`` on ``address`` (launched by this process); returns its entry, for
    :func:`withdraw`."""
    folder = launches_dir()
    entry = folder / f"{os.getpid()}-{next(_entries)}.json"
    record = {"bus": str(address), "pid": os.getpid(), "started": _start_time(os.getpid()),
              "run_dir": str(run_dir.resolve())}
    for _ in range(3):  # a withdraw may remove the empty folder between the mkdir and the write
        with contextlib.suppress(OSError):
            folder.mkdir(mode=0o700, parents=True, exist_ok=True)
            write_beside(entry, json.dumps(record) + "\n")  # never half a file (readers read *.json only)
            break
    latest = run_dir.parent / "latest"
    if run_dir.parent.name != "runs" or run_dir.name == "latest" or (latest.exists() and not latest.is_symlink()):
        return entry  # only runs/latest (not /tmp/latest for --run-dir /tmp/x), and never over a real file
    with contextlib.suppress(OSError), written_beside(latest, per_writer=True) as link:  # launches start at once
        link.symlink_to(run_dir.name)
    return entry


def withdraw(entry: Path) -> None:
    """Remove a launch's entry (it ended); the directory goes too once no launch runs."""
    with contextlib.suppress(OSError):
        entry.unlink()
    with contextlib.suppress(OSError):
        entry.parent.rmdir()  # only when empty


def _start_time(pid: int) -> int | None:
    """When process ``pid`` started (clock ticks since boot, from /proc), or None where that cannot be read."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
        return int(stat.rpartition(")")[2].split()[19])  # field 22; the name before ")" may hold spaces
    except (OSError, ValueError, IndexError):
        return None


def _alive(pid: int, started: object) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return started is None or started == _start_time(pid)  # the pid reused by another process: gone


def _read(path: Path) -> RunningLaunch | None:
    """The launch an entry names, or None when the entry is unreadable or its launcher is gone."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict):
        return None
    bus, pid, run_dir = data.get("bus"), data.get("pid"), data.get("run_dir")
    if not (isinstance(bus, str) and isinstance(pid, int) and isinstance(run_dir, str)):
        return None
    return RunningLaunch(bus, pid, run_dir) if _alive(pid, data.get("started")) else None


def running_launches() -> list[RunningLaunch]:
    """The launches running now (their launchers alive), by run directory; stale entries are removed."""
    found = []
    with contextlib.suppress(OSError):
        for path in sorted(launches_dir().glob("*.json")):
            launch = _read(path)
            if launch is None:
                with contextlib.suppress(OSError):
                    path.unlink()  # a killed launcher's: it misleads nobody again
            else:
                found.append(launch)
    return sorted(found, key=lambda launch: launch.run_dir)


def _choose(launches: list[RunningLaunch]) -> str:
    lines = "\n".join(f"  --run {launch.run_dir}   (bus {launch.bus}, launcher pid {launch.pid})"
                      for launch in launches)
    return (f"{len(launches)} launches are running; not guessing which one to address. Say which with --run RUN "
            f"(a run directory, or its name) or --bus ADDRESS:\n{lines}")


def find_bus(bus: str | None = None, run: Path | None = None) -> tuple[BusAddress, str]:
    """The bus a CLI tool should use, and where that choice came from (for messages such as "no nodes heard
    on ... (the launch in runs/x)"). Raises :class:`BusError` naming the candidates when more than one launch
    runs and nothing says which."""
    if bus:
        return BusAddress.parse(bus), "--bus"
    if run is not None:
        address_file = run / "bus.address"
        try:
            text = address_file.read_text(encoding="utf-8").strip()
        except OSError:
            named = [launch for launch in running_launches() if Path(launch.run_dir).name == str(run)]
            if len(named) == 1:
                return BusAddress.parse(named[0].bus), f"the launch in {named[0].run_dir}"
            raise BusError(f"--run {run}: no {address_file} (is it the run directory of a launch?)"
                           + (f"\n{_choose(named)}" if named else "")) from None
        return BusAddress.parse(text), f"the launch in {run}"
    env = palpa_env.get(palpa_env.BUS)
    if env:
        return BusAddress.parse(env), "$PALPA_BUS"
    launches = running_launches()
    if len(launches) > 1:
        raise BusError(_choose(launches))
    if launches:
        return BusAddress.parse(launches[0].bus), f"the running launch in {launches[0].run_dir}"
    return BusAddress.parse(default_address()), "the default bus; no launch is running"
