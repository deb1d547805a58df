"""The transport to the bus an address names: the process's in-memory bus for ``memq://NAME``
(:mod:`palpa.net.memory`), ZeroMQ sockets (:class:`palpa.net.transport.ZmqTransport`) for any other."""

from __future__ import annotations

from palpa import env as palpa_env
from palpa.net.address import BusAddress, from_env
from palpa.net.memory import memq_name, named_bus
from palpa.net.transport import Transport, TransportOptions, ZmqTransport

__all__ = ["bus_transport"]


def bus_transport(bus: str | BusAddress | None, options: TransportOptions | None) -> Transport:
    """The transport to the bus ``bus`` names (else ``PALPA_BUS``, else the default bus): the process's in-memory
    bus for ``memq://NAME``, ZeroMQ sockets otherwise."""
    if not isinstance(bus, BusAddress):
        text = bus or palpa_env.get(palpa_env.BUS) or ""
        if (name := memq_name(text)) is not None:
            return named_bus(name).transport()
    address = bus if isinstance(bus, BusAddress) else (BusAddress.parse(bus) if bus else from_env())
    return ZmqTransport(address, options or TransportOptions.from_env())
