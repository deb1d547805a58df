"""How a process finds the bus: three ZeroMQ endpoints named by one string.

``PALPA_BUS`` (or ``--bus``) holds one of:

* ``ipc:///tmp/palpa-NAME``   -> ``ipc:///tmp/palpa-NAME.pub``, ``.sub``, ``.latch``
* ``tcp://HOST:PORT``         -> ports PORT, PORT+1, PORT+2 on HOST
* ``pub=EP;sub=EP;latch=EP``  -> explicit endpoints (what ``palpa bus`` prints when the OS chose the ports)

``pub`` is where publishers connect (the proxy's XSUB), ``sub`` where subscribers connect (its XPUB), ``latch``
the last-value cache (a ROUTER). The default, with nothing set, is ``ipc://<private dir>/bus``, where the private
directory is ``$XDG_RUNTIME_DIR/palpa`` or ``/tmp/palpa-<uid>``, made 0700 and checked to be this user's and
closed to others (another local user must not be able to create it first and take the bus's place).
"""

from __future__ import annotations

import ipaddress
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from palpa import env as palpa_env
from palpa.errors import BusError

__all__ = ["BusAddress", "check_ipc_owner", "default_address", "from_env", "is_loopback_host", "private_dir"]

_IPC_MAX = 100  # the kernel's sun_path limit is 107 bytes; keep a margin for the suffix


@dataclass(frozen=True)
class BusAddress:
    """The three endpoints of one bus."""

    pub: str
    sub: str
    latch: str

    @classmethod
    def parse(cls, text: str) -> BusAddress:
        """Parse any of the three spellings in the module docstring; raises :class:`BusError` otherwise."""
        text = text.strip()
        if text.startswith("memq://"):
            raise BusError(f"bus address {text!r}: an in-memory bus is reached only by nodes of the process it lives "
                           "in (Node(bus=...), PALPA_BUS in that process); a launch or a tool needs ipc:// or tcp://")
        if "=" in text:
            parts: dict[str, str] = {}
            for item in filter(None, text.split(";")):
                key, sep, value = item.partition("=")
                if not sep or key not in ("pub", "sub", "latch"):
                    raise BusError(f"bus address {text!r}: expected pub=...;sub=...;latch=..., got {item!r}")
                parts[key] = value
            missing = {"pub", "sub", "latch"} - parts.keys()
            if missing:
                raise BusError(f"bus address {text!r}: missing {', '.join(sorted(missing))}")
            return cls(parts["pub"], parts["sub"], parts["latch"])
        if text.startswith("ipc://"):
            path = text[len("ipc://") :]
            if not path:
                raise BusError(f"bus address {text!r}: empty ipc path")
            if len(path) + len(".latch") > _IPC_MAX:
                raise BusError(
                    f"bus address {text!r}: ipc path is {len(path)} characters; keep it under "
                    f"{_IPC_MAX - len('.latch')} (the kernel limit is 107)"
                )
            return cls(f"ipc://{path}.pub", f"ipc://{path}.sub", f"ipc://{path}.latch")
        if text.startswith("tcp://"):
            hostport = text[len("tcp://") :]
            host, sep, port_s = hostport.rpartition(":")
            if not sep or not host:
                raise BusError(f"bus address {text!r}: expected tcp://HOST:PORT")
            try:
                port = int(port_s)
            except ValueError:
                raise BusError(f"bus address {text!r}: port {port_s!r} is not a number") from None
            if port == 0 or port == -1:
                raise BusError(
                    f"bus address {text!r}: give a fixed base port, or let `palpa bus --tcp HOST` choose "
                    "and use the explicit address it prints"
                )
            if not 0 < port < 65534:
                raise BusError(f"bus address {text!r}: port {port} out of range")
            return cls(
                f"tcp://{host}:{port}", f"tcp://{host}:{port + 1}", f"tcp://{host}:{port + 2}"
            )
        raise BusError(f"bus address {text!r}: expected ipc://PATH, tcp://HOST:PORT or pub=..;sub=..;latch=..")

    def __str__(self) -> str:
        return f"pub={self.pub};sub={self.sub};latch={self.latch}"


def private_dir() -> Path:
    """This user's directory for ipc sockets (created 0700): ``$XDG_RUNTIME_DIR/palpa`` when that is set and
    private, else ``/tmp/palpa-<uid>``. Raises :class:`BusError` when it exists but belongs to someone else or
    others may enter it."""
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    base = Path(xdg) / "palpa" if xdg and _is_private(Path(xdg)) else Path(f"/tmp/palpa-{os.getuid()}")
    try:
        base.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise BusError(f"cannot create the private socket directory {base}: {exc.strerror or exc}") from None
    st = os.lstat(base)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise BusError(f"{base} is not a private directory of this user (owner uid {st.st_uid}, mode "
                       f"{stat.S_IMODE(st.st_mode):04o}; expected uid {os.getuid()}, 0700): another user may have "
                       "made it to receive and inject messages; remove it or set PALPA_BUS")
    return base


def _is_private(path: Path) -> bool:
    try:
        st = os.stat(path)
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & 0o077


def default_address() -> str:
    """The bus used when nothing says otherwise: one per user, on ipc, in :func:`private_dir`."""
    return f"ipc://{private_dir()}/bus"


def from_env() -> BusAddress:
    """The bus named by ``PALPA_BUS``, or the default one."""
    return BusAddress.parse(palpa_env.get(palpa_env.BUS) or default_address())


def is_loopback_host(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ``::1``, ``[::1]``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_ipc_owner(endpoint: str) -> None:
    """Refuse an ipc socket another user made: it is their bus, not ours (they would read what we publish)."""
    if not endpoint.startswith("ipc://"):
        return
    try:
        owner = os.stat(endpoint[len("ipc://") :]).st_uid
    except OSError:
        return  # not there yet: the bus starts later (ZeroMQ connects when it appears)
    if owner not in (os.getuid(), 0):
        raise BusError(f"{endpoint} belongs to uid {owner}, not to this user: refusing to connect to another "
                       "user's socket")
