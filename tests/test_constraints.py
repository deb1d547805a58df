"""constraints.txt pins what `make` installs: every requirement of pyproject.toml (extras included) must be pinned
there, exactly once, at a version inside pyproject's range. A dependency added to pyproject.toml without a pin would
install whatever is newest on a fresh machine (CI), the drift the lock exists to stop; a pin outside the range
would make pip refuse to install at all."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

REPO = Path(__file__).resolve().parent.parent


def pins(text: str) -> dict[str, list[Version]]:
    """Package name (canonical) -> the versions pinned with ``==`` in a constraints file's text."""
    out: dict[str, list[Version]] = {}
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        req = Requirement(line)
        spec = list(req.specifier)
        assert len(spec) == 1 and spec[0].operator == "==", f"constraints.txt: {raw!r} is not an exact pin"
        out.setdefault(canonicalize_name(req.name), []).append(Version(spec[0].version))
    return out


def requirements(pyproject: dict[str, object]) -> list[Requirement]:
    """Every requirement of the project and of each of its extras."""
    project = pyproject["project"]
    assert isinstance(project, dict)
    reqs = [Requirement(r) for r in project["dependencies"]]
    for extra in project.get("optional-dependencies", {}).values():
        reqs += [Requirement(r) for r in extra]
    return reqs


def unmet(pyproject: dict[str, object], constraints: str) -> list[str]:
    """What is wrong between the two files, one line per problem (empty: the lock covers pyproject)."""
    pinned = pins(constraints)
    problems = [f"{name} pinned {len(v)} times" for name, v in pinned.items() if len(v) > 1]
    for req in requirements(pyproject):
        versions = pinned.get(canonicalize_name(req.name))
        if not versions:
            problems.append(f"{req.name}: in pyproject.toml, not pinned in constraints.txt")
        elif not req.specifier.contains(versions[0], prereleases=True):
            problems.append(f"{req.name}: pinned {versions[0]}, outside pyproject's {req.specifier}")
    return problems


def test_every_requirement_is_pinned_once_inside_its_range() -> None:
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert unmet(pyproject, (REPO / "constraints.txt").read_text()) == []


def test_a_missing_or_out_of_range_pin_is_named() -> None:
    pyproject = {"project": {"dependencies": ["numpy>=1.26", "pytest>=8,<9.2"],
                             "optional-dependencies": {"bench": ["eclipse-zenoh>=1.0"]}}}
    assert unmet(pyproject, "numpy==2.4.6\npytest==9.1.1\neclipse-zenoh==1.10.2\n") == []
    assert unmet(pyproject, "numpy==2.4.6\npytest==9.2.0\n") == [
        "pytest: pinned 9.2.0, outside pyproject's <9.2,>=8",
        "eclipse-zenoh: in pyproject.toml, not pinned in constraints.txt"]
    assert unmet(pyproject, "# header\nNumPy==2.4.6\nnumpy==2.0\npytest==9.1.1\neclipse_zenoh==1.0\n") == [
        "numpy pinned 2 times"]
