"""The layering rules that code review keeps forgetting, checked on the source: no import cycles between files of
the product (nodes/ included, even under TYPE_CHECKING), no module reading or importing another module's underscore
names, emulators that import nothing from nodes/ (an emulator tested against its driver's own codec proves
nothing), and node classes whose ``params`` is typed as their own ``Params``. The wall-clock census is in
tests/test_wall_clock.py."""

from __future__ import annotations

import ast
import importlib
import sys
import typing
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("palpa", "emulators", "yamlstruct", "models", "messages", "devices", "tools", "nodes")
ALLOWED_PRIVATE = {
    "argparse._SubParsersAction",  # the stdlib's only name for a subparsers annotation
    "os._exit",  # documented: exit without the interpreter's teardown (palpa.exiting)
    "atexit._run_exitfuncs",  # the exit handlers, which palpa.exiting runs before os._exit: no public name
}


def plant_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, files: dict[str, str]) -> None:
    """A package ``fakepkg`` of ``files`` (name -> source; an empty ``__init__.py`` unless given) under
    ``tmp_path``, made the root the scans of this module walk: a check shown to find what it looks for."""
    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    for name, text in {"__init__.py": "", **files}.items():
        (pkg / name).write_text(text)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)


def source_modules(packages: tuple[str, ...]) -> dict[str, Path]:
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
    mods = source_modules(packages)
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
    for path in source_modules(packages).values():
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
    for path in source_modules(packages).values():
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
    mods = source_modules(PACKAGES)
    used = _imports("palpa.timing.compose", mods["palpa.timing.compose"], set(mods))
    assert not {m for m in used if m == "palpa.testing" or m == "palpa.cli" or m.startswith("palpa.cli.")}


def test_no_module_reads_another_modules_private_names() -> None:
    assert foreign_private_access(PACKAGES) == []
    assert private_imports(PACKAGES) == []


def test_emulators_import_nothing_from_nodes() -> None:
    mods = source_modules(("emulators",))
    known = set(source_modules(("emulators", "nodes")))
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
ESTIMATORS = {"models.contact", "models.multi_indenter_solve", "models.multi_indenter_batch", "models.stiffness_map",
              "models.detector", "models.false_alarm", "models.background", "models.peaks", "models.calibration_airfloat",
              "models.camera_calibration", "models.tracker", "models.kalman",
              "models.adaptive", "models.adaptive_detect", "models.adaptive_budget", "models.adaptive_cover",
              "models.adaptive_split", "models.scoring", "nodes.probe.stiffness_estimator", "nodes.probe.estimator_multi",
              "nodes.mapping.map_aggregator"}
AIRFLOAT_GEOMETRY = {"DEFAULT_INDENTER_RADIUS_MM", "DEFAULT_SPS_RADIUS_MM", "heights_over_phantom"}


def world_reaches_into_estimators(world: tuple[str, ...], estimators: set[str],
                                  airfloat_geometry: set[str] = AIRFLOAT_GEOMETRY) -> list[str]:
    """Every import by a world module of an estimator module, or of a models.airfloat name that is not geometry."""
    mods = source_modules(("models", "nodes", "emulators"))
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
    plant_package(tmp_path, monkeypatch, {
        "a.py": "from fakepkg import b\n",
        "b.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fakepkg.a import x\n"
                "def f(node):\n    return node._depth\n",
        "c.py": "from fakepkg.a import _secret\n"})
    assert import_cycles(("fakepkg",)) == [["fakepkg.a", "fakepkg.b"]]
    assert foreign_private_access(("fakepkg",)) == ["fakepkg/b.py:5: node._depth"]
    assert private_imports(("fakepkg",)) == ["fakepkg/c.py:1: from fakepkg.a import _secret"]


def test_only_palpa_env_names_palpa_variables() -> None:
    """The environment is read in one place: no other runtime module spells a ``PALPA_*`` name as a string."""
    import re

    spelt = []
    for name, path in source_modules(("palpa",)).items():
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
    known = set(source_modules(("palpa", "yamlstruct", "models")))
    for pkg in ("yamlstruct", "models"):
        for m, p in source_modules((pkg,)).items():
            assert not [t for t in _imports(m, p, known) if t.split(".")[0] == "palpa"], m


def untyped_params(classes: list[type[Any]]) -> list[str]:
    """The node classes whose ``params`` is not annotated as their own ``Params`` (mypy would then check no
    ``self.params.<name>``: the base class declares only :class:`palpa.Params`)."""
    from palpa.node.node import Node

    return [f"{c.__module__}.{c.__qualname__}" for c in classes
            if c.Params is not Node.Params and typing.get_type_hints(c).get("params") is not c.Params]


def _project_node_classes() -> list[type[Any]]:
    from palpa.node.node import Node

    for name in source_modules(("palpa", "nodes")):
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
    for name, path in source_modules(packages).items():
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
    plant_package(tmp_path, monkeypatch,
                  {"__init__.py": "import yaml\n\ndef f(t):\n    return yaml.safe_dump(yaml.safe_load(t))\n"})
    assert yaml_read_outside_yamlstruct(("fakepkg",)) == ["fakepkg/__init__.py:4: yaml.safe_load"]
