"""The launch-file format, as msgspec Structs: the loader validates against these and ``palpa launch --schema``
prints the JSON Schema generated from them, so the two can never disagree.

A launch file (YAML)::

    description: talker and listener
    args:
      - {name: rate, default: 10.0, description: talker rate in Hz}
    nodes:
      - name: talker
        node: nodes.demo:Talker            # or  cmd: [program, arg, ...]
        params: {rate_hz: $(arg rate)}
      - {name: listener, node: nodes.demo:Listener, output: log}
    include:
      - {file: other.yaml, args: {robot: sim}, namespace: left}
    bus: {transport: ipc, latched: [scan/plan]}
    record: {topics: ["probe/.*"], exclude: ["camera/.*"]}
    progress: {topic: robot/scan_status}
    viz: {enabled: $(arg viz), client_publish: [robot/estop]}

Values are native YAML types. A string that is exactly ``$(arg name)`` takes the argument's value with its type,
so the schema below also accepts such a string wherever it expects a number or a boolean.
"""

from __future__ import annotations

import copy
from typing import Annotated, Any, Literal

import msgspec
from msgspec import UNSET, Meta, Struct, UnsetType, field

from palpa.net.options import TransportOptions

__all__ = [
    "NAME_PATTERN",
    "ArgDecl",
    "BusDecl",
    "IncludeDecl",
    "LaunchFile",
    "NodeDecl",
    "ProgressDecl",
    "RecordDecl",
    "VizDecl",
    "json_schema",
]

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_-]*$"
NAMESPACE_PATTERN = r"^(/?[A-Za-z0-9_]+(/[A-Za-z0-9_]+)*)?$"
SUBST_PATTERN = r"^\$\(arg [A-Za-z][A-Za-z0-9_-]*\)$"

Name = Annotated[str, Meta(pattern=NAME_PATTERN, description="letters, digits, '_' and '-'; starts with a letter")]
Namespace = Annotated[str, Meta(pattern=NAMESPACE_PATTERN, description="prefix for relative topic names")]
_FOREVER_S = 1e9  # a timeout beyond ~30 years is a typo (or .inf): refused
Seconds = Annotated[float, Meta(ge=0.0, le=_FOREVER_S)]


class _Decl(Struct, kw_only=True, forbid_unknown_fields=True):
    pass


class ArgDecl(_Decl):
    """A launch argument: given on the command line (``name:=value``) or by an include, else its default."""

    name: Name
    default: Annotated[Any, Meta(description="native YAML value; omit to make the arg required")] | UnsetType = UNSET
    description: str = ""


class NodeDecl(_Decl):
    """One process of the graph: a palpa node class (``node``) or any executable (``cmd``)."""

    name: Name
    node: Annotated[str, Meta(pattern=r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$",
                              description="package.module:Class of a palpa.Node subclass")] | None = None
    cmd: Annotated[list[str], Meta(min_length=1, description="argv of any executable; params in env PALPA_PARAMS "
                                                            "as JSON")] | None = None
    params: Annotated[dict[str, Any], Meta(description="validated against the node's Params before launch")] = {}
    remap: Annotated[dict[str, str], Meta(description="topic -> topic")] = {}
    namespace: Namespace = ""
    env: Annotated[dict[str, str], Meta(description="extra environment variables (strings)")] = {}
    respawn: Annotated[bool, Meta(description="start again when it fails (exits non-zero or is killed); exit "
                                              "code 0 means it has finished")] = False
    respawn_delay: Annotated[float, Meta(gt=0.0, le=_FOREVER_S, description="seconds before the first respawn; doubles after "
                                                              "each consecutive one (capped at 60 s)")] = 1.0
    respawn_max_retries: Annotated[int, Meta(ge=-1, description="consecutive respawns before giving up; "
                                                                 "-1: never give up")] = 5
    required: Annotated[bool, Meta(description="when it exits (for good) the whole launch ends with its "
                                               "exit code")] = False
    sigterm_timeout: Annotated[Seconds, Meta(description="seconds after SIGINT before SIGTERM")] = 5.0
    sigkill_timeout: Annotated[Seconds, Meta(description="seconds after SIGTERM before SIGKILL")] = 5.0
    output: Annotated[Literal["screen", "log"], Meta(description="screen: lines shown as `[name] line`; "
                                                                  "always kept in <run_dir>/<name>.log")] = "screen"
    transport: TransportOptions | None = None
    if_: Annotated[bool, Meta(description="false: leave this node out (e.g. `if: $(arg viz)`)")] = field(
        default=True, name="if")


class IncludeDecl(_Decl):
    """Another launch file whose nodes join this graph. ``file`` is relative to the including file."""

    file: str
    args: Annotated[dict[str, Any], Meta(description="values for the included file's args")] = {}
    namespace: Annotated[Namespace, Meta(description="prefixed to the included nodes' namespaces")] = ""


class BusDecl(_Decl):
    """Where the launcher's in-process bus listens. Default: a fresh ipc path per run."""

    transport: Literal["ipc", "tcp"] = "ipc"
    endpoint: Annotated[str, Meta(description="ipc: a path or ipc://PATH; tcp: tcp://HOST:PORT (PORT..PORT+2) "
                                              "or tcp://HOST (ports chosen by the OS)")] | None = None
    latched: Annotated[list[str], Meta(description="topics whose last message is replayed to late "
                                                   "subscribers")] = []
    hwm: Annotated[int, Meta(gt=0, description="high-water mark of the proxy sockets (messages)")] = 10_000
    max_msg_bytes: Annotated[int, Meta(ge=1024, description="the largest frame the bus accepts; a publisher "
                                                            "sending a larger one is disconnected")] = 16 * 2**20


class RecordDecl(_Decl):
    """Record the run to <run_dir>/recording.mcap with the recorder node (started first, stopped last)."""

    topics: Annotated[list[str], Meta(description="regular expressions; empty: every topic")] = []
    exclude: Annotated[list[str], Meta(description="regular expressions of topics to leave out")] = []
    split_size_mb: Annotated[float, Meta(gt=0)] | None = None
    split_duration_s: Annotated[float, Meta(gt=0, le=_FOREVER_S)] | None = None
    ready_timeout_s: Annotated[float, Meta(gt=0, le=_FOREVER_S, description="how long to wait for the recorder's "
                                                             "heartbeat")] = 15.0
    required: Annotated[bool, Meta(description="a recorder that dies stops the launch (exit 1) instead of "
                                               "letting the rest of the run go unrecorded")] = True


class VizDecl(_Decl):
    """Serve the graph to Foxglove with the bridge node ``viz`` (palpa.viz.bridge:Bridge), started first."""

    enabled: Annotated[bool, Meta(description="false: no bridge (e.g. `enabled: $(arg viz)`)")] = True
    host: Annotated[str, Meta(description="interface; beyond loopback needs allow_remote")] = "127.0.0.1"
    port: Annotated[int, Meta(ge=0, le=65535, description="0: the OS chooses (see <run_dir>/viz.address)")] = 8765
    allow_remote: bool = False
    topics: Annotated[list[str], Meta(description="regular expressions; empty: every topic")] = []
    exclude: Annotated[list[str], Meta(description="regular expressions of topics to leave out")] = []
    client_publish: Annotated[list[str], Meta(description="topics a Foxglove client may publish, e.g. "
                                                          "robot/estop")] = []


class ProgressDecl(_Decl):
    """Show a progress bar from messages on ``topic`` with fields progress (0..1) and optionally state, message,
    eta_s, line, lines."""

    topic: str
    report: Annotated[list[str], Meta(description="nodes whose last lines hidden by the bar (their results) are "
                                                  "printed after it")] = []


class LaunchFile(_Decl):
    """A palpa launch file."""

    description: str = ""
    args: list[ArgDecl] = []
    python_path: Annotated[list[str], Meta(description="folders added to the import path of the launcher and "
                                                       "every node; relative to this file")] = []
    include: list[IncludeDecl] = []
    prepare: Annotated[list[Annotated[list[str], Meta(min_length=1)]], Meta(
        description="commands run one after the other, each to exit 0, after the run directory exists and before "
                    "any node starts (e.g. a simulation's setup writing a file the nodes read); 'python' is the "
                    "launcher's own interpreter")] = []
    nodes: list[NodeDecl] = []
    bus: BusDecl | None = None
    record: Annotated[bool | RecordDecl, Meta(description="true: record every topic")] | None = None
    progress: ProgressDecl | None = None
    viz: Annotated[bool | VizDecl, Meta(description="true: serve every topic to Foxglove on "
                                                    "ws://127.0.0.1:8765")] | None = None
    in_process: Annotated[bool, Meta(description="run the simulated-clock nodes (env PALPA_SIM_CLOCK=1), the clock "
                                                 "and the recorder in one process whose clock jumps from event to "
                                                 "event (palpa.timing.compose); also palpa launch --in-process")] = False


def json_schema() -> dict[str, Any]:
    """The JSON Schema of a launch file, generated from :class:`LaunchFile`. Wherever a number or boolean is
    expected, a ``$(arg name)`` string is accepted too (it is replaced by the arg's native value on load)."""
    schema: dict[str, Any] = copy.deepcopy(msgspec.json.schema(LaunchFile))
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "palpa launch file"
    out: dict[str, Any] = _allow_arg_substitution(schema)
    return out


def _allow_arg_substitution(schema: Any) -> Any:
    if isinstance(schema, list):
        return [_allow_arg_substitution(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    out = {k: _allow_arg_substitution(v) for k, v in schema.items()}
    if out.get("type") in ("number", "integer", "boolean") or "enum" in out:
        keep = {k: out.pop(k) for k in ("default", "description", "title") if k in out}
        return {"anyOf": [out, {"type": "string", "pattern": SUBST_PATTERN}], **keep}
    return out
