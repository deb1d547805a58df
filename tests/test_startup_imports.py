"""What a launcher imports before it starts anything: checking a launch file imports every node class it names (to
check their parameters), and a composed run's start-up is serial (the launcher checks, then the composition
imports the same classes). Packages that take a large part of a second to import (scipy's ndimage and optimize,
matplotlib) are imported by the functions that use them, not at the top of a module a node class pulls in
(issue 40). Checked on the source: the module-level imports reachable from the demo's node classes, and from the
launch verb."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from palpa.launch.loader import load_launch
from tests.test_architecture import ROOT, plant_package, source_modules

HEAVY = ("scipy", "matplotlib", "sklearn", "cv2", "pandas", "pyarrow", "dask")
"""Packages a launcher checking the demo must not import: each costs 0.1 s or more (``python -X importtime``)."""


def _top_level_imports(path: Path) -> list[str]:
    """The modules a file imports when it is imported: its top-level statements (into ``if``/``try`` blocks), not
    the bodies of functions or classes, nor ``if TYPE_CHECKING:`` blocks."""
    found: list[str] = []
    todo: list[ast.stmt] = list(ast.parse(path.read_text(), str(path)).body)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            found += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.If):
            if not (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"):
                todo += node.body + node.orelse
        elif isinstance(node, ast.Try):
            todo += node.body + node.orelse + node.finalbody + [s for h in node.handlers for s in h.body]
    return found


def _walk(roots: list[str], packages: tuple[str, ...]) -> tuple[set[str], list[str]]:
    """The project modules importing ``roots`` imports at module level (the package ``__init__`` files on the way
    included), and ``module: imported`` for each heavy package among their imports."""
    mods = source_modules(packages)
    seen: set[str] = set()
    todo = list(roots)
    out = []
    while todo:
        name = todo.pop()
        if name in seen or name not in mods:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        for target in _top_level_imports(mods[name]):
            if target.split(".")[0] in HEAVY:
                out.append(f"{name}: {target}")
            t = target
            while t and t not in mods:
                t = t.rpartition(".")[0]
            if t:
                todo.append(t)
    return seen, sorted(set(out))


def heavy_imports(roots: list[str], packages: tuple[str, ...]) -> list[str]:
    """``module: imported`` for each heavy package imported at module level by a project module that importing
    ``roots`` imports (the package ``__init__`` files on the way included)."""
    return _walk(roots, packages)[1]


def test_checking_the_demo_imports_no_heavy_package(tmp_path: Path) -> None:
    plan = load_launch(ROOT / "launch" / "scan_sim.yaml", run_dir=tmp_path)
    roots = ["palpa.cli.main", "palpa.timing.compose"] + [s.target.partition(":")[0] for s in plan.nodes if s.target]
    assert "nodes.mapping.map_aggregator" in roots
    assert heavy_imports(roots, ("palpa", "models", "nodes", "messages", "devices", "yamlstruct")) == []


def test_the_check_sees_a_heavy_import_at_module_level(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plant_package(tmp_path, monkeypatch, {
        "a.py": "from fakepkg import b\n\ndef f():\n    import matplotlib\n",
        "b.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pandas\n"
                "try:\n    from scipy import ndimage\nexcept ImportError:\n    pass\n"})
    assert heavy_imports(["fakepkg.a"], ("fakepkg",)) == ["fakepkg.b: scipy", "fakepkg.b: scipy.ndimage"]


def test_the_launcher_starts_a_composition_before_importing_the_node_runtime() -> None:
    """``palpa launch --in-process`` starts the composed simulation as soon as it has read the file; the node runtime
    (palpa.node, ~50 ms with numpy and the wire) is imported afterwards, by the checks it runs meanwhile
    (palpa.startgate). So nothing the launch verb imports at module level may import it."""
    seen, _ = _walk(["palpa.cli.main", "palpa.cli.launch"], ("palpa", "yamlstruct"))
    assert "palpa.launch.supervisor" in seen and "palpa.launch.loader" in seen
    assert sorted(m for m in seen if m.startswith(("palpa.node", "palpa.targets", "palpa.timing.simclock"))) == []


def test_the_map_detector_needs_no_scipy_ndimage() -> None:
    """The detector runs in every process that publishes a map; scipy.ndimage alone takes ~0.16 s to import, so its
    three operations are models.grid_filters' (equal to the bit, tests/test_grid_filters.py), at any level."""
    for module in ("models/detector.py", "models/grid_filters.py"):
        tree = ast.parse((ROOT / module).read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        names += [f"{n.module}.{a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names]
        assert not [m for m in names if "ndimage" in m], module
