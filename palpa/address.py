"""How a process finds the bus: three ZeroMQ endpoints named by one string.

``PALPA_BUS`` (or ``--bus``) holds one of:

* ``ipc:///tmp/palpa-NAME``   -> ``ipc:///tmp/palpa-NAME.pub``, ``.sub``, ``.latch``
* ``tcp://HOST:PORT``         -> ports PORT, PORT+1, PORT+2 on HOST
* ``pub=EP;sub=EP;latch=EP``  -> explicit endpoints (what ``palpa bus`` prints when the OS chose the ports)

``pub`` is where publishers connect (the proxy's XSUB), ``sub`` where subscribers connect (its XPUB), ``latch``
the last-value cache (a ROUTER). The default, with nothing set, is ``ipc:///tmp/palpa-<uid>``.
"""

from __future__ import annotations

import ipaddress
import os
from dataclasses import dataclass

from palpa.errors import BusError

__all__ = ["BusAddress", "default_address", "from_env", "is_loopback_host"]

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

    @property
    def is_tcp(self) -> bool:
        return self.pub.startswith("tcp://")


def default_address() -> str:
    """The bus used when nothing says otherwise: one per user, on ipc."""
    return f"ipc:///tmp/palpa-{os.getuid()}"


def from_env() -> BusAddress:
    """The bus named by ``PALPA_BUS``, or the default one."""
    return BusAddress.parse(os.environ.get("PALPA_BUS") or default_address())


def is_loopback_host(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ``::1``, ``[::1]``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
