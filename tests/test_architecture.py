"""The layering rules that code review keeps forgetting, checked on the source: no import cycles between files of
the product (nodes/ included, even under TYPE_CHECKING), no module reading or importing another module's underscore
names, emulators that import nothing from nodes/ (an emulator tested against its driver's own codec proves
nothing), node classes whose ``params`` is typed as their own ``Params``, and product code that reads the wall clock
only in the places listed with why."""

from __future__ import annotations

import ast
import importlib
import sys
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("palpa", "emulators", "yamlstruct", "models", "messages", "devices", "tools", "nodes")
ALLOWED_PRIVATE = {"argparse._SubParsersAction"}  # the stdlib's only name for a subparsers annotation


def _modules(packages: tuple[str, ...]) -> dict[str, Path]:
    out = {}
    for pkg in packages:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """Every project module ``name`` imports (at top level, under TYPE_CHECKING or inside functions alike)."""
    is_pkg = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                pkg = pkg[: len(pkg) - node.level + 1]
                base = ".".join([*pkg, base] if base else pkg)
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def import_cycles(packages: tuple[str, ...]) -> list[list[str]]:
    """Strongly connected components of more than one module in the import graph (Tarjan)."""
    mods = _modules(packages)
    graph = {m: _imports(m, p, set(mods)) for m, p in mods.items()}
    # a package's __init__ re-exports its modules: importing it is not a cycle with them
    for m in graph:
        graph[m] = {t for t in graph[m] if not (mods[t].name == "__init__.py" and m.startswith(t + "."))}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def foreign_private_access(packages: tuple[str, ...]) -> list[str]:
    """``obj._name`` (obj not self/cls) where the module does not define ``_name`` itself: a reach into another
    module's private state."""
    bad = []
    for path in _modules(packages).values():
        tree = ast.parse(path.read_text(), str(path))
        own: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                own.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                own.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                own.add(node.id)
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                own.add(node.target.id)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            text = ast.unparse(node)
            if node.attr not in own and text not in ALLOWED_PRIVATE:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {text}")
    return bad


def private_imports(packages: tuple[str, ...]) -> list[str]:
    """``from m import _name``: a module taking another module's private name (``obj._x`` reads are the other check)."""
    bad = []
    for path in _modules(packages).values():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                bad += [f"{path.relative_to(ROOT)}:{node.lineno}: from {node.module} import {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    return bad


def test_no_import_cycles_in_the_product() -> None:
    assert import_cycles(PACKAGES) == []


def test_the_in_process_executor_imports_neither_the_test_kit_nor_the_cli() -> None:
    """``palpa launch --in-process`` runs on the composition: product code, whose in-memory bus is palpa.net.memory
    (issue 38), not the test kit's."""
    mods = _modules(PACKAGES)
    used = _imports("palpa.timing.compose", mods["palpa.timing.compose"], set(mods))
    assert not {m for m in used if m == "palpa.testing" or m == "palpa.cli" or m.startswith("palpa.cli.")}


def test_no_module_reads_another_modules_private_names() -> None:
    assert foreign_private_access(PACKAGES) == []
    assert private_imports(PACKAGES) == []


def test_emulators_import_nothing_from_nodes() -> None:
    mods = _modules(("emulators",))
    known = set(_modules(("emulators", "nodes")))
    offenders = {m: sorted(t for t in _imports(m, p, known) if t.startswith("nodes")) for m, p in mods.items()}
    assert {m: t for m, t in offenders.items() if t} == {}


# The simulated world (tissue mechanics, sensors and their errors) and the estimators (the papers' methods) share no
# formula (docs/physics.md §7). The world may use the probes' geometry (models.multi_indenter's tip layout, the
# air-float probe's radii and what its sensors read over a surface), never an inversion.
WORLD = ("models.world", "models.airfloat_device", "models.camera_world", "models.camera_render",
         "nodes.drivers.fibre_sim", "nodes.drivers.camera_sim", "nodes.drivers.pressure_sim",
         "nodes.drivers.robot_sim", "emulators")
# models.fibre_calibration is not among them: it is the DAQ's own counts <-> mm curve, which the emulated DAQ
# encodes with as the real one does (fibre_sim's world adds the sensor's gain and bow errors on top)
ESTIMATORS = {"models.contact", "models.multi_indenter_solve", "models.stiffness_map", "models.detector",
              "models.calibration_airfloat",
              "models.camera_calibration", "models.tracker", "models.kalman",
              "models.adaptive", "models.scoring", "nodes.probe.stiffness_estimator", "nodes.probe.estimator_multi",
              "nodes.mapping.map_aggregator"}
AIRFLOAT_GEOMETRY = {"DEFAULT_INDENTER_RADIUS_MM", "DEFAULT_SPS_RADIUS_MM", "heights_over_phantom"}


def world_reaches_into_estimators(world: tuple[str, ...], estimators: set[str],
                                  airfloat_geometry: set[str] = AIRFLOAT_GEOMETRY) -> list[str]:
    """Every import by a world module of an estimator module, or of a models.airfloat name that is not geometry."""
    mods = _modules(("models", "nodes", "emulators"))
    bad = []
    for name, path in mods.items():
        if not any(name == w or name.startswith(w + ".") for w in world):
            continue
        bad += [f"{name} -> {t}" for t in sorted(_imports(name, path, set(mods))) if t in estimators]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module == "models.airfloat":
                bad += [f"{name} -> models.airfloat.{a.name}" for a in node.names if a.name not in airfloat_geometry]
    return bad


def test_the_simulated_world_imports_no_estimator() -> None:
    assert world_reaches_into_estimators(WORLD, ESTIMATORS) == []


def test_the_world_check_sees_an_estimator_import() -> None:
    """The check is not vacuous: the camera sim reads the probe geometry, which counts once it is called an
    estimator, and the fibre sim's airfloat import counts once heights are not geometry."""
    assert "nodes.drivers.camera_sim -> models.multi_indenter" in world_reaches_into_estimators(
        WORLD, ESTIMATORS | {"models.multi_indenter"})
    assert "nodes.drivers.fibre_sim -> models.airfloat.heights_over_phantom" in world_reaches_into_estimators(
        WORLD, ESTIMATORS, AIRFLOAT_GEOMETRY - {"heights_over_phantom"})


def test_the_checks_see_a_cycle_and_a_private_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The scans are not vacuous: a planted cycle and a planted private read are found."""
    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from fakepkg import b\n")
    (pkg / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fakepkg.a import x\n"
                              "def f(node):\n    return node._depth\n")
    (pkg / "c.py").write_text("from fakepkg.a import _secret\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert import_cycles(("fakepkg",)) == [["fakepkg.a", "fakepkg.b"]]
    assert foreign_private_access(("fakepkg",)) == ["fakepkg/b.py:5: node._depth"]
    assert private_imports(("fakepkg",)) == ["fakepkg/c.py:1: from fakepkg.a import _secret"]


def test_only_palpa_env_names_palpa_variables() -> None:
    """The environment is read in one place: no other runtime module spells a ``PALPA_*`` name as a string."""
    import re

    spelt = []
    for name, path in _modules(("palpa",)).items():
        if name == "palpa.env":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and \
                    re.fullmatch(r"PALPA_[A-Z0-9_]+", node.value):
                spelt.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value}")
    assert spelt == []


def test_every_variable_is_documented() -> None:
    from palpa.env import VARIABLES

    doc = (ROOT / "docs" / "launch.md").read_text()
    assert [v for v in VARIABLES if f"| `{v}` |" not in doc] == []


def test_yamlstruct_and_models_do_not_import_the_runtime() -> None:
    """models/ are pure and read YAML through yamlstruct, which must stay free of palpa (its __init__ pulls in
    ZeroMQ and the node loop)."""
    known = set(_modules(("palpa", "yamlstruct", "models")))
    for pkg in ("yamlstruct", "models"):
        for m, p in _modules((pkg,)).items():
            assert not [t for t in _imports(m, p, known) if t.split(".")[0] == "palpa"], m


def untyped_params(classes: list[type[Any]]) -> list[str]:
    """The node classes whose ``params`` is not annotated as their own ``Params`` (mypy would then check no
    ``self.params.<name>``: the base class declares only :class:`palpa.Params`)."""
    from palpa.node.node import Node

    return [f"{c.__module__}.{c.__qualname__}" for c in classes
            if c.Params is not Node.Params and typing.get_type_hints(c).get("params") is not c.Params]


def _project_node_classes() -> list[type[Any]]:
    from palpa.node.node import Node

    for name in _modules(("palpa", "nodes")):
        if not name.endswith("__main__"):
            importlib.import_module(name)
    found, todo = [], [Node]
    while todo:
        for sub in todo.pop().__subclasses__():
            todo.append(sub)
            if sub.__module__.split(".")[0] in ("palpa", "nodes"):
                found.append(sub)
    return found


def test_every_node_class_types_its_params() -> None:
    classes = _project_node_classes()
    assert {"nodes.probe.stiffness_estimator.AirfloatStiffnessEstimator", "palpa.record.player.Player"} <= {
        f"{c.__module__}.{c.__qualname__}" for c in classes}
    assert untyped_params(classes) == []


def test_the_params_check_sees_a_node_that_forgot_the_annotation() -> None:
    import palpa

    class Forgot(palpa.Node):
        class Params(palpa.Params):
            rate_hz: float = 1.0

    class Typed(palpa.Node):
        class Params(palpa.Params):
            rate_hz: float = 1.0

        params: Params

    assert untyped_params([Forgot, Typed, palpa.Node]) == [f"{__name__}.{Forgot.__qualname__}"]


YAML_READERS = {"safe_load", "load", "full_load", "unsafe_load", "compose", "safe_load_all", "load_all"}


def yaml_read_outside_yamlstruct(packages: tuple[str, ...]) -> list[str]:
    """Every call of a PyYAML reader outside yamlstruct/ (writing with ``yaml.safe_dump`` is fine)."""
    found = []
    for name, path in _modules(packages).items():
        if name.split(".")[0] == "yamlstruct":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "yaml" \
                    and node.attr in YAML_READERS:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: yaml.{node.attr}")
    return found


def test_yaml_is_read_only_through_yamlstruct() -> None:
    """One YAML reader (YAML 1.2 scalars, duplicate keys refused, file:line:col in every error): launch files,
    parameter files, phantoms, calibrations and geometries all go through yamlstruct."""
    assert yaml_read_outside_yamlstruct(("palpa", "models", "nodes", "emulators", "devices", "messages", "bench",
                                         "yamlstruct")) == []


def test_the_yaml_check_sees_a_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("import yaml\n\ndef f(t):\n    return yaml.safe_dump(yaml.safe_load(t))\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert yaml_read_outside_yamlstruct(("fakepkg",)) == ["fakepkg/__init__.py:4: yaml.safe_load"]


# -- time: every wait and deadline of the product reads the node's clock (palpa.timing.clock) --------------------------
PRODUCT = ("palpa", "nodes", "models", "messages", "devices", "emulators", "tools", "yamlstruct")
WALL_CLOCK = {"monotonic", "monotonic_ns", "time", "time_ns", "sleep", "perf_counter", "perf_counter_ns"}
WALL_DATES = {"now", "utcnow", "today"}


def _scopes(tree: ast.AST) -> dict[ast.AST, str]:
    """Every node of ``tree`` mapped to the dotted name of the def/class it sits in ("" at module level)."""
    where: dict[ast.AST, str] = {}

    def visit(node: ast.AST, scope: str) -> None:
        for child in ast.iter_child_nodes(node):
            inner = scope
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                inner = f"{scope}.{child.name}" if scope else child.name
            where[child] = inner
            visit(child, inner)

    visit(tree, "")
    return where


def _wall_clock_use(node: ast.AST, time_names: set[str]) -> str | None:
    """What ``node`` reads of the wall clock, if anything: a ``time`` function (called or handed on as a clock),
    one imported from ``time``, today's date, or a blocking wait bounded by a timeout."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in time_names \
            and node.attr in WALL_CLOCK:
        return f"time.{node.attr}"
    if isinstance(node, ast.ImportFrom) and node.module == "time":
        names = sorted(a.name for a in node.names if a.name in WALL_CLOCK)
        return f"from time import {', '.join(names)}" if names else None
    if isinstance(node, ast.Attribute) and node.attr in WALL_DATES and \
            ast.unparse(node.value) in ("datetime", "date", "datetime.datetime", "datetime.date"):
        return f"{ast.unparse(node.value)}.{node.attr}"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        timeout = any(k.arg == "timeout" for k in node.keywords)
        if node.func.attr == "wait" and (node.args or timeout):
            return f"{ast.unparse(node.func)}(timeout)"
        if node.func.attr == "get" and timeout:
            return f"{ast.unparse(node.func)}(timeout=)"
    return None


def wall_clock_reads(packages: tuple[str, ...]) -> dict[str, list[str]]:
    """Every read of the wall clock in ``packages``, as ``{"module:Scope.name": ["line: what", ...]}``."""
    found: dict[str, list[str]] = {}
    for name, path in _modules(packages).items():
        tree = ast.parse(path.read_text(), str(path))
        time_names = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.Import)
                      for a in n.names if a.name == "time"}
        scopes = _scopes(tree)
        for node in ast.walk(tree):
            what = _wall_clock_use(node, time_names)
            if what is not None:
                scope = scopes.get(node, "")
                found.setdefault(f"{name}:{scope}" if scope else name, []).append(f"{node.lineno}: {what}")
    return {k: sorted(v, key=lambda s: int(s.split(":")[0])) for k, v in found.items()}


# The places that read the wall clock on purpose, each with why. A key is a module, or a module and the def or class
# (everything inside it) that does. Everything else waits and decides on its node's clock (palpa.timing.clock.Deadline,
# a node's timers, or a clock handed to a driver).
WALL_CLOCK_ALLOWED = {
    # the clock implementations
    "palpa.timing.clock": "the clocks themselves: SystemClock is the wall clock; Deadline measures a SystemClock "
                          "on the monotonic clock behind it",
    "palpa.timing.simclock": "the lockstep clock node: it paces simulated time against the wall and times out "
                             "nodes that stop answering (a clock implementation)",
    "palpa.record.player": "palpa play is a clock implementation: it replays recorded time at a wall-clock rate "
                           "(and publishes it as the simulation clock), waiting wall time for its listeners",
    "palpa.timing.compose:Composition.__init__": "the composition's simulated time starts at the wall clock's "
                                                 "whole second (an origin, not a wait)",
    "palpa.timing.compose:Composition._take_outside": "rate-limits a syscall: how often a busy composition looks "
                                                      "at the real bus through its bridge",
    "palpa.timing.compose:main": "reports how many times faster than real time a composition ran",
    "nodes.mapping.map_output:_end": "a helper process's exit lives in wall time: the wait bounds it, then kills it "
                                     "(the map node draws the picture itself when the helper fails)",
    "palpa.node.node_time:SimTime.await_first_tick": "before the first tick simulated time does not exist: only "
                                                     "wall time can bound the wait for it",
    "palpa.node.node_time:SimTime.on_clock": "the frozen-time watchdog notes when a tick came, in wall time",
    "palpa.node.node_time:SimTime.on_instant": "the frozen-time watchdog notes when time moved, in wall time",
    "palpa.node.node_time:SimTime.check_alive": "the frozen-time watchdog: when simulated time stops, only the "
                                                "wall clock can tell",
    # sockets, processes, files and the people reading them live in wall time; none of these is a decision of a
    # node's logic
    "palpa.node.presence:confirm_subscriptions": "ZeroMQ subscriptions travel through the proxy in wall time, and "
                                                 "a lockstep clock holds simulated time until the node is ready: "
                                                 "JOIN_TIMEOUT_S on the node's clock would never pass",
    "palpa.node.presence:Heartbeats": "heartbeats are wall-clock liveness for launchers and `palpa node list`, "
                                      "whatever the node's clock (a paused replay's node is alive)",
    "palpa.node.receive:Receiver.count_error": "rate-limits a log line for the human reading it",
    "palpa.node.receive:Receiver._handle": "a raw message's recv_ns is the MCAP log time a recorder writes: when "
                                           "the host received it, on its wall clock (a record, not a decision)",
    "palpa.lograte": "rate-limits log lines (what a peer can make happen at will) for the human reading them",
    "palpa.net.direct:DirectSocket.drain": "stamps the transport's own reach answers (no node, no node clock)",
    "palpa.net.transport:ZmqTransport._busy_wait": "a busy-poll timeout bounds a socket read, not a decision",
    "palpa.net.transport:ZmqTransport._wait_fine": "a sub-ms poll timeout bounds a socket read, not a decision",
    "palpa.net.transport:ZmqTransport._await_proxy": "the proxy's handshake is a socket's, in wall time",
    "palpa.net.handshake:HandshakeWatch": "waits for and retries a CURVE handshake with the proxy: sockets",
    "palpa.launch": "the launcher supervises processes, which live in wall time: exit waits, restart back-off, "
                    "the stop grace, the console's time of day",
    "palpa.cli": "command-line tools talk to a user in wall time (echo/hz windows, --timeout, a unique tool "
                 "node name) and say so",
    "palpa.viz.server": "the websocket viewer refreshes a browser in wall time",
    "palpa.record.recorder:Recorder.setup": "a recording's start time is wall-clock metadata of the file",
    "palpa.record.recorder:Recorder._open_file": "a file's open time is wall-clock metadata of the file",
    "palpa.record.recorder:Recorder.spin": "after stop, drains what its sockets already hold, bounded in wall "
                                           "time (a simulated clock may have stopped with the graph)",
    "tools.evaluate": "reports the wall time a run took, to a user",
    # drivers: hardware lives in wall time; what a node decides about it reads the clock the node hands in
    "nodes.drivers.host_clock": "the clock of a driver used without a node (every node hands in its own)",
    "nodes.drivers.camera:OpenCVSource._run": "the capture thread of a camera (or of a video paced as one): frames "
                                              "come in wall time, and a thread blocks in wall time between them",
    "nodes.drivers.camera:SimSource.read": "the realtime pacing its docstring reserves for a wall clock",
    "nodes.drivers.fibre_serial:SerialFibreDriver._run": "the serial reader thread's reconnect back-off: a port",
    "nodes.drivers.robot_urrtde:URRtdeDriver._monitor_loop": "paces the thread that polls the controller",
    "nodes.drivers.robot_urrtde:URRtdeDriver._kick": "the controller times the RTDE watchdog on its own wall "
                                                     "clock: the kicks that feed it, and the gaps between them, too",
    "nodes.drivers.robot_urrtde:URRtdeDriver._set_watchdog": "arms the RTDE watchdog (see _kick)",
    "nodes.drivers.robot_urrtde:URRtdeDriver._stop_cause": "tells a starved RTDE watchdog (see _kick)",
    # emulators stand in for hardware in another thread or process, which lives in wall time
    "emulators.alicat": "an emulated device (its default clock when a test hands it none)",
    "emulators.fibre_daq": "an emulated device streams on its own wall clock, as the DAQ does",
    "emulators.pty_device": "the pseudo-terminal's reader thread and unplug wait",
    "emulators.ur.server": "the UR emulator serves ur_rtde over TCP in wall time (the system tier); its steppable "
                           "core, emulators.ur.stepper, runs on the clock it is given (the monotonic one here)",
    "emulators.ur.process": "starts, waits for and stops an emulator process",
    "emulators.ur.__main__": "palpa-urfake's main thread waits for a signal",
}


def _listed(key: str, allowed: Mapping[str, str]) -> bool:
    return any(key == a or key.startswith((a + ".", a + ":")) for a in allowed)


def test_product_code_reads_the_wall_clock_only_where_listed() -> None:
    """A wait or a decision on the wall clock fires early when the machine is busy and the node runs on simulated
    time; product code reads its node's clock (palpa.timing.clock.Deadline) except in the listed places."""
    found = wall_clock_reads(PRODUCT)
    assert {k: v for k, v in found.items() if not _listed(k, WALL_CLOCK_ALLOWED)} == {}


def test_every_listed_wall_clock_place_still_reads_it() -> None:
    """The list shrinks with the code: a place that no longer reads the wall clock leaves it."""
    found = wall_clock_reads(PRODUCT)
    assert [a for a in WALL_CLOCK_ALLOWED if not any(_listed(k, {a: ""}) for k in found)] == []


def test_the_wall_clock_census_sees_each_kind_of_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "import time as t\nimport queue\nfrom time import monotonic, strftime\nfrom datetime import datetime\n"
        "class A:\n    def f(self, ev, q, clock=t.time_ns):\n        t.sleep(0.1)\n        ev.wait(0.5)\n"
        "        q.get(timeout=1)\n        return datetime.now(), ev.wait(), q.get(), ', '.join([strftime('%H')])\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert wall_clock_reads(("fakepkg",)) == {
        "fakepkg": ["3: from time import monotonic"],
        "fakepkg:A.f": ["6: time.time_ns", "7: time.sleep", "8: ev.wait(timeout)", "9: q.get(timeout=)",
                        "10: datetime.now"]}
    assert _listed("fakepkg:A.f", {"fakepkg:A": ""}) and not _listed("fakepkg:A.f", {"fakepkg:A.g": ""})
