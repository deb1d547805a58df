"""palpa: a ROS-style node graph without ROS — typed msgpack messages over ZeroMQ, YAML launch files, MCAP logs.

Layering (imports point downwards only)::

    palpa.cli        command-line verbs (bus, topic, node, service, param, launch, record, play, bag)
    palpa.launch     launch files and the process supervisor
    palpa.record     MCAP recording and replay
    palpa.node.node       the Node API: publishers, subscriptions, timers, parameters (what it declares kept in
                     palpa.node.inventory; its time and lockstep side in palpa.node.node_time; readiness,
                     heartbeats and bus logging in palpa.node.presence)
    palpa.node.service    services (request/reply over the bus; callers in palpa.node.service_client), run-time
                     parameters on top of them (palpa.node.params_runtime)
    palpa.net.transport  ZeroMQ (and, in palpa.testing, in-memory) transports
    palpa.net.bus        the XSUB/XPUB proxy and latched-value cache
    palpa.net.wire       the envelope; palpa.message the typed-message base and registry

This package knows nothing about palpation: the domain lives in ``messages``, ``models`` and ``nodes``.
"""

from typing import TYPE_CHECKING, Any

from palpa.errors import BusError, DecodeError, LaunchError, PalpaError, ParamError, RegistryError

if TYPE_CHECKING:
    from palpa.message import Finite, Message, json_schema, lookup, registered
    from palpa.net.address import BusAddress
    from palpa.node.node import MsgInfo, Node, Publisher, RawMessage, Subscription, Timer
    from palpa.node.params import (
        InputPath,
        NonNegative,
        Params,
        Positive,
        PositiveInt,
        RunTime,
        SafetyLimit,
    )
    from palpa.node.runner import run_node
    from palpa.timing.clock import Clock, MockClock, SystemClock

# The names below are imported at first use (PEP 562): ``import palpa.X`` for one tool (the launcher, a CLI verb)
# then does not pay for the whole node runtime (~65 ms, numpy and ZeroMQ included) before it can start its work.
_LAZY = {
    "palpa.message": ("Finite", "Message", "json_schema", "lookup", "registered"),
    "palpa.net.address": ("BusAddress",),
    "palpa.node.node": ("MsgInfo", "Node", "Publisher", "RawMessage", "Subscription", "Timer"),
    "palpa.node.params": ("InputPath", "NonNegative", "Params", "Positive", "PositiveInt", "RunTime", "SafetyLimit"),
    "palpa.node.runner": ("run_node",),
    "palpa.timing.clock": ("Clock", "MockClock", "SystemClock"),
}
_WHERE = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'palpa' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))


__version__ = "0.1.0"

__all__ = [
    "BusAddress",
    "BusError",
    "Clock",
    "DecodeError",
    "Finite",
    "InputPath",
    "LaunchError",
    "Message",
    "MockClock",
    "Node",
    "PalpaError",
    "ParamError",
    "NonNegative",
    "Params",
    "Positive",
    "PositiveInt",
    "Publisher",
    "MsgInfo",
    "RawMessage",
    "RegistryError",
    "RunTime",
    "SafetyLimit",
    "Subscription",
    "SystemClock",
    "Timer",
    "__version__",
    "json_schema",
    "lookup",
    "registered",
    "run_node",
]
