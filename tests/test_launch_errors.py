"""The corpus of malformed launch files: each gives one clear error at the right file:line:col.

Line 1 of every ``tests/launch_errors/*.yaml`` says what is expected::

    # expect: [OTHER_FILE:]LINE:COL: message fragment

(OTHER_FILE, relative to the corpus folder, when the error is in a file it includes.)
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from palpa.errors import LaunchError
from palpa.launch import load_launch

CORPUS = Path(__file__).resolve().parent / "launch_errors"
FILES = sorted(CORPUS.glob("*.yaml"))
_EXPECT_RE = re.compile(r"^# expect: (?:(?P<file>[\w./-]+\.yaml):)?(?P<line>\d+):(?P<col>\d+): (?P<text>.+)$")


def expectation(path: Path) -> tuple[str, int, int, str]:
    first = path.read_text().splitlines()[0] if path.read_text() else ""
    m = _EXPECT_RE.match(first)
    if m is None:
        raise AssertionError(f"{path}: line 1 must be '# expect: [FILE:]LINE:COL: fragment', not {first!r}")
    return m.group("file") or path.name, int(m.group("line")), int(m.group("col")), m.group("text").strip()


def test_corpus_is_big_enough() -> None:
    assert len(FILES) >= 20


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_malformed_file_names_line_and_column(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(CORPUS)  # messages name files relative to the working directory
    monkeypatch.delenv("PALPA_TEST_SURELY_UNSET_42", raising=False)
    file, line, col, text = expectation(path)
    with pytest.raises(LaunchError) as info:
        load_launch(path.name)
    message = str(info.value)
    assert message.startswith(f"{file}:{line}:{col}: "), message
    assert text in message, message
    assert "\n" not in message and "Traceback" not in message


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "palpa.cli.main", "launch", *args], capture_output=True,
                          text=True, timeout=60, cwd=CORPUS, env={**os.environ, "PYTHONPATH": str(CORPUS.parents[1])})


@pytest.mark.system
def test_cli_prints_one_line_and_exits_1_and_debug_shows_traceback() -> None:
    plain = _cli("--check", "param_wrong_type.yaml")
    assert plain.returncode == 1
    assert plain.stderr == ("param_wrong_type.yaml:7:16: param 'rate_hz' of node 'talker': "
                            "expected `float`, got `str`\n")
    debug = _cli("--check", "--debug", "param_wrong_type.yaml")
    assert debug.returncode != 0 and "Traceback" in debug.stderr


@pytest.mark.system
def test_cli_unknown_override_names_the_declared_args() -> None:
    res = _cli("--check", "included/talker_rate.yaml", "rat:=3")
    assert res.returncode == 1
    assert "unknown arg 'rat' given by the command line (did you mean 'rate'?)" in res.stderr


@pytest.mark.system
def test_cli_wrong_typed_override_names_the_param_line_and_the_arg() -> None:
    res = _cli("--check", "included/talker_rate.yaml", "rate:=fast")
    assert res.returncode == 1
    assert res.stderr.startswith("included/talker_rate.yaml:7:23: param 'rate_hz' of node 'talker': expected "
                                 "`float`, got `str`"), res.stderr
    assert "from arg 'rate' = \"fast\", given by the command line (rate:=...)" in res.stderr


@pytest.mark.system
def test_cli_missing_phantom_given_on_the_command_line_fails_the_check() -> None:
    res = _cli("--check", str(CORPUS.parents[1] / "launch" / "scan_sim.yaml"), "phantom:=nowhere.yaml")
    assert res.returncode == 1
    assert "param 'phantom' of node 'fibre': 'nowhere.yaml' does not exist" in res.stderr
    assert "given by the command line (phantom:=...)" in res.stderr and "Traceback" not in res.stderr
