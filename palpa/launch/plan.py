"""The resolved graph: what the loader produces and the supervisor runs (no YAML, no substitutions left)."""

from __future__ import annotations

import itertools
import json
import os
import secrets
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from palpa import env as palpa_env
from palpa.errors import BusError
from palpa.launch.schema import BusDecl, RecordDecl, VizDecl
from palpa.net.address import BusAddress, private_dir
from palpa.net.options import TransportOptions

__all__ = ["RECORDER_NAME", "RECORDER_TARGET", "VIZ_NAME", "VIZ_READY", "VIZ_TARGET", "LaunchPlan", "NodeSpec"]

_FRESH = itertools.count()
"""Numbers this process's fresh bus paths (LaunchPlan.bus_request)."""

RECORDER_NAME = "recorder"
RECORDER_TARGET = "palpa.record.recorder:Recorder"
VIZ_NAME = "viz"
VIZ_TARGET = "palpa.viz.bridge:Bridge"
VIZ_READY = "palpa viz ready "
"""How the bridge's line announcing its URL begins (``palpa viz ready ws://HOST:PORT ...``): the launcher shows
the URL even under a progress bar."""


@dataclass
class NodeSpec:
    """One process to supervise, fully resolved. ``where`` is the ``file:line:col`` of its entry."""

    name: str
    target: str | None = None
    cmd: list[str] | None = None
    params: dict[str, Any] = field(default_factory=dict)
    remap: dict[str, str] = field(default_factory=dict)
    namespace: str = ""
    env: dict[str, str] = field(default_factory=dict)
    respawn: bool = False
    respawn_delay: float = 1.0
    respawn_max_retries: int = 5
    required: bool = False
    sigterm_timeout: float = 5.0
    sigkill_timeout: float = 5.0
    output: str = "screen"
    transport: TransportOptions | None = None
    """Transport options set by the launch file (None: the child reads its own environment and flags)."""
    where: str = ""
    gate: bool = False
    """It may start before the file's ``prepare`` commands and wait for the launcher's go (palpa.startgate): the
    composed simulation, whose imports then overlap the prepare step."""

    def argv(self) -> list[str]:
        """The command line of the child: ``palpa run`` for a node class, ``cmd`` as given otherwise."""
        if self.cmd is not None:
            return list(self.cmd)
        if self.target is None:
            raise ValueError(f"node {self.name!r} has neither target nor cmd")
        argv = [sys.executable, "-m", "palpa.cli.main", "run", self.target, "--name", self.name,
                "--namespace", self.namespace, "--params-json", json.dumps(self.params)]
        for src, dst in self.remap.items():
            argv += ["--remap", f"{src}:={dst}"]
        return argv

    def child_env(self, base: dict[str, str], *, bus: BusAddress | None, run_dir: Path,
                  python_path: list[str]) -> dict[str, str]:
        """The child's environment: ``base`` + PALPA_BUS, PALPA_RUN_DIR, PALPA_NODE_NAME, PYTHONUNBUFFERED=1,
        PYTHONPATH (the launch files' python_path first), PALPA_PARAMS/PALPA_REMAP/PALPA_NAMESPACE as JSON for
        ``cmd`` entries, the transport options (PALPA_TRANSPORT), then the entry's own ``env``."""
        env = dict(base)
        if bus is not None:
            env[palpa_env.BUS] = str(bus)
        env[palpa_env.RUN_DIR] = str(run_dir)
        env[palpa_env.NODE_NAME] = self.name
        env["PYTHONUNBUFFERED"] = "1"
        if python_path:
            env["PYTHONPATH"] = os.pathsep.join([*python_path, *filter(None, [base.get("PYTHONPATH")])])
        if self.cmd is not None:
            env[palpa_env.PARAMS] = json.dumps(self.params)
            env[palpa_env.REMAP] = json.dumps(self.remap)
            env[palpa_env.NAMESPACE] = self.namespace
        if self.transport is not None:
            env.update(self.transport.to_env())
        env.update(self.env)
        return env

    def as_dict(self) -> dict[str, Any]:
        """The entry as launch-file YAML would write it (every field explicit)."""
        out: dict[str, Any] = {"name": self.name}
        if self.target is not None:
            out["node"] = self.target
        else:
            out["cmd"] = list(self.cmd or [])
        out.update(params=self.params, remap=self.remap, namespace=self.namespace, env=self.env,
                   respawn=self.respawn, respawn_delay=self.respawn_delay,
                   respawn_max_retries=self.respawn_max_retries, required=self.required,
                   sigterm_timeout=self.sigterm_timeout, sigkill_timeout=self.sigkill_timeout, output=self.output)
        if self.transport is not None:
            out["transport"] = self.transport.given()
        return out


@dataclass
class LaunchPlan:
    """A launch file with its includes flattened and every substitution applied."""

    file: Path
    run_dir: Path
    description: str = ""
    args: dict[str, Any] = field(default_factory=dict)
    nodes: list[NodeSpec] = field(default_factory=list)
    python_path: list[str] = field(default_factory=list)
    prepare: list[list[str]] = field(default_factory=list)
    """Commands run before any node starts (included files' first, in the order read)."""
    bus: BusDecl = field(default_factory=BusDecl)
    record: RecordDecl | None = None
    progress_topic: str | None = None
    progress_report: list[str] = field(default_factory=list)
    recorder_available: bool = False
    viz: VizDecl | None = None
    """The Foxglove bridge the ``viz`` section asks for (enabled), or None."""
    node_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Node name -> every parameter of a ``node:`` entry, defaults included (filled by the loader)."""
    files: list[str] = field(default_factory=list)
    """Every launch file read, the top-level one first."""
    included_args: dict[str, list[str]] = field(default_factory=dict)
    """Included file -> the args the command line set in it (docs/launch.md, "Includes")."""
    in_process: bool = False
    """The file asks for its simulated-clock nodes in one process (see :mod:`palpa.launch.compose`)."""
    pending_checks: Callable[[], None] | None = field(default=None, repr=False, compare=False)
    """The loader's node-class checks, when the caller asked to run them itself (``load_launch(...,
    defer_node_checks=True)``): they raise the same :class:`LaunchError` as a plain load would."""
    composed_from: str | None = None
    """The resolved launch file this plan was composed from (:func:`palpa.launch.compose.compose_plan`):
    :meth:`to_yaml` gives it, so the run directory and the recording describe the graph as written (a replay
    reads its nodes' parameters there), not the one process it ran in."""

    def recorder(self) -> NodeSpec | None:
        """The recorder node the ``record`` section asks for (None without one)."""
        if self.record is None:
            return None
        params: dict[str, Any] = {
            "output": str(self.run_dir / "recording.mcap"),
            "topics": list(self.record.topics),
            "exclude": list(self.record.exclude),
            "launch_file": str(self.run_dir / "launch.resolved.yaml"),
        }
        if self.record.split_size_mb is not None:
            params["split_size_mb"] = self.record.split_size_mb
        if self.record.split_duration_s is not None:
            params["split_duration_s"] = self.record.split_duration_s
        # the recorder imports these only for a type it cannot find otherwise (palpa.record.format)
        modules = dict.fromkeys(n.target.partition(":")[0] for n in self.nodes if n.target)
        return NodeSpec(name=RECORDER_NAME, target=RECORDER_TARGET, params=params, sigterm_timeout=10.0,
                        sigkill_timeout=5.0, where=f"{self.files[0] if self.files else self.file}: record",
                        env={palpa_env.NODE_MODULES: ",".join(modules)})

    def viz_node(self) -> NodeSpec | None:
        """The bridge node the ``viz`` section asks for (None without one): an ordinary node entry named ``viz``,
        respawned if it fails (a viewer must not end a scan)."""
        v = self.viz
        if v is None:
            return None
        params = {"host": v.host, "port": v.port, "allow_remote": v.allow_remote, "topics": list(v.topics),
                  "exclude": list(v.exclude), "client_publish": list(v.client_publish)}
        return NodeSpec(name=VIZ_NAME, target=VIZ_TARGET, params=params, respawn=True,
                        where=f"{self.files[0] if self.files else self.file}: viz")

    def bus_request(self, override: str | None = None) -> BusAddress:
        """The endpoints the launcher binds: ``override`` (``--bus-address``), else the ``bus`` section, else a
        fresh ipc path ``<private dir>/<pid>-<n>-<4 hex>`` (palpa.net.address.private_dir; n counts the process's
        requests, so two are never the same in one process, and the hex part keeps a reused pid's apart)."""
        if override:
            return _tcp_any(override) if _is_host_only(override) else BusAddress.parse(override)
        endpoint = self.bus.endpoint
        if self.bus.transport == "tcp":
            if endpoint is None:
                return _tcp_any("tcp://127.0.0.1")
            if not endpoint.startswith("tcp://"):
                endpoint = "tcp://" + endpoint
            return _tcp_any(endpoint) if _is_host_only(endpoint) else BusAddress.parse(endpoint)
        if endpoint is None:
            return BusAddress.parse(f"ipc://{private_dir()}/{os.getpid()}-{next(_FRESH)}-{secrets.token_hex(2)}")
        if endpoint.startswith("tcp://"):
            raise BusError(f"bus endpoint {endpoint!r} is tcp but transport is ipc")
        return BusAddress.parse(endpoint if endpoint.startswith("ipc://") else f"ipc://{endpoint}")

    def to_yaml(self) -> str:
        """The resolved graph as a launch file (loadable again: no includes, args fixed to their values)."""
        if self.composed_from is not None:
            return self.composed_from
        doc: dict[str, Any] = {}
        if self.description:
            doc["description"] = self.description
        doc["args"] = [{"name": k, "default": v} for k, v in self.args.items()]
        if self.python_path:
            doc["python_path"] = list(self.python_path)
        if self.prepare:
            doc["prepare"] = [list(c) for c in self.prepare]
        doc["nodes"] = [n.as_dict() for n in self.nodes]
        doc["bus"] = {"transport": self.bus.transport, "endpoint": self.bus.endpoint,
                      "latched": list(self.bus.latched), "hwm": self.bus.hwm}
        if self.record is not None:
            r = self.record
            doc["record"] = {"topics": list(r.topics), "exclude": list(r.exclude), "split_size_mb": r.split_size_mb,
                             "split_duration_s": r.split_duration_s, "ready_timeout_s": r.ready_timeout_s}
        if self.progress_topic is not None:
            doc["progress"] = {"topic": self.progress_topic, "report": list(self.progress_report)}
        if self.in_process:
            doc["in_process"] = True
        header = "".join(f"# {line}\n" for line in [
            f"resolved from {self.files[0] if self.files else self.file}",
            *(f"includes {f}" for f in self.files[1:]),
            f"run directory {self.run_dir}",
        ])
        return header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def _is_host_only(address: str) -> bool:
    """``tcp://HOST`` (no port, or port 0 / *): let the OS choose three ports."""
    if not address.startswith("tcp://") or "=" in address:
        return False
    rest = address[len("tcp://"):]
    if rest.startswith("["):
        return "]:" not in rest or rest.rsplit(":", 1)[1] in ("", "0", "*")
    return ":" not in rest or rest.rsplit(":", 1)[1] in ("", "0", "*")


def _tcp_any(address: str) -> BusAddress:
    rest = address[len("tcp://"):]
    host = rest.rsplit(":", 1)[0] if (":" in rest and not rest.endswith("]")) else rest
    ep = f"tcp://{host}:*"
    return BusAddress(ep, ep, ep)
