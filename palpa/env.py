"""Every ``PALPA_*`` environment variable, declared and read here and nowhere else.

The launcher sets most of them on its children; a user sets ``PALPA_BUS``, ``PALPA_MESSAGES`` and the CURVE keys.
Readers elsewhere call :func:`get` (or :func:`listed`) with a name from :data:`VARIABLES`, so that a variable's
name, meaning and parsing live in one place (docs/launch.md lists them from this table).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

__all__ = ["BUS", "BUS_SERVER_KEY", "CLOCK_KEY", "CLOCK_MASTER_KEY", "CURRENT", "CURVE_SECRET", "DIRECT_HOST",
           "MESSAGES", "NAMESPACE", "NODE_MODULES",
           "NODE_NAME", "PARAMS", "REMAP", "RUN_DIR", "SIM_CLOCK", "SIM_CLOCK_MAX_JUMP_S", "SIM_CLOCK_TIMEOUT_S",
           "START_GATE", "TRANSPORT", "VARIABLES", "flag", "get", "listed"]

BUS = "PALPA_BUS"
RUN_DIR = "PALPA_RUN_DIR"
NODE_NAME = "PALPA_NODE_NAME"
PARAMS = "PALPA_PARAMS"
REMAP = "PALPA_REMAP"
NAMESPACE = "PALPA_NAMESPACE"
SIM_CLOCK = "PALPA_SIM_CLOCK"
SIM_CLOCK_TIMEOUT_S = "PALPA_SIM_CLOCK_TIMEOUT_S"
SIM_CLOCK_MAX_JUMP_S = "PALPA_SIM_CLOCK_MAX_JUMP_S"
TRANSPORT = "PALPA_TRANSPORT"
MESSAGES = "PALPA_MESSAGES"
NODE_MODULES = "PALPA_NODE_MODULES"
CURRENT = "PALPA_CURRENT"
BUS_SERVER_KEY = "PALPA_BUS_SERVER_KEY"
CURVE_SECRET = "PALPA_CURVE_SECRET"
DIRECT_HOST = "PALPA_DIRECT_HOST"
CLOCK_KEY = "PALPA_CLOCK_KEY"
CLOCK_MASTER_KEY = "PALPA_CLOCK_MASTER_KEY"
START_GATE = "PALPA_START_GATE"

VARIABLES: dict[str, str] = {
    BUS: "the bus address a node or tool joins (else the one running launch's, else the default bus)",
    RUN_DIR: "set by the launcher: the run directory (logs, recordings, the viz address)",
    NODE_NAME: "set by the launcher: the node's name in the launch file",
    PARAMS: "set by the launcher on `cmd:` entries: the parameters as a JSON object",
    REMAP: "set by the launcher on `cmd:` entries: the remaps as a JSON object",
    NAMESPACE: "set by the launcher on `cmd:` entries: the node's namespace",
    SIM_CLOCK: "1: follow simulated time on _palpa/clock (as --sim-clock)",
    SIM_CLOCK_TIMEOUT_S: "wall seconds without a clock tick after which a sim-clock node stops (0: never)",
    SIM_CLOCK_MAX_JUMP_S: "simulated seconds a tick (or a message's instant) may move a sim-clock node's time forward "
                          "at once; a longer jump is refused, logged and counted (default 60; 0: no bound)",
    TRANSPORT: "the node's transport options as one JSON object (palpa.net.options.TransportOptions; the launcher "
               "sets it from `transport:`)",
    MESSAGES: "extra message modules, comma-separated (for tools, the recorder and viz)",
    NODE_MODULES: "set by the launcher on its recorder: the launched node classes' modules, comma-separated",
    CURRENT: "the directory of running launches the tools choose from (default: in the private runtime directory)",
    BUS_SERVER_KEY: "the CURVE server's public key (Z85 text or a .key file) of an encrypted bus",
    CURVE_SECRET: "the path to this client's .key_secret file on an encrypted bus",
    DIRECT_HOST: "the address this node's direct topics are served on when the bus is on another host (default: "
                 "this host's address on the route to the bus)",
    CLOCK_KEY: "set by the launcher: this node's key (hex) to sign its lockstep clock acks (palpa.timing.acksign)",
    CLOCK_MASTER_KEY: "set by the launcher on its clock entry: the run's master key (hex), from which the clock "
                      "derives each node's key to check its acks' signatures",
    START_GATE: "set by the launcher on a composed simulation it starts before its prepare commands: the file "
                "descriptor to read its go from (palpa.startgate)",
}


def get(name: str, env: Mapping[str, str] | None = None) -> str:
    """The value of variable ``name`` (one of :data:`VARIABLES`), stripped; "" when unset."""
    if name not in VARIABLES:
        raise KeyError(f"{name} is not a palpa environment variable (palpa.env.VARIABLES)")
    return (os.environ if env is None else env).get(name, "").strip()


def flag(name: str, env: Mapping[str, str] | None = None) -> bool:
    """Whether a yes/no variable is set to something other than "" or "0"."""
    return get(name, env) not in ("", "0")


def listed(name: str, env: Mapping[str, str] | None = None) -> list[str]:
    """A comma-separated variable as a list (empty items dropped)."""
    return [item.strip() for item in get(name, env).split(",") if item.strip()]
