"""Command-line args reach included launch files (issue 42, docs/launch.md "Includes"): an arg given on the command
line sets the same-named arg of every file read, at any depth, unless the include sets that arg itself; an arg no
file declares is still an error, and so is one every include that could take it overrides."""

from __future__ import annotations

from pathlib import Path

import pytest

from palpa.errors import LaunchError
from palpa.launch import load_launch, parse_overrides
from tests.test_launch_loader import write
from tests.test_launch_smoke import REPO

SCAN = REPO / "launch" / "scan_sim.yaml"


def test_a_wrapper_around_the_shipped_scan_takes_its_args_from_the_command_line(tmp_path: Path) -> None:
    wrapper = write(tmp_path / "my.yaml", f"""\
        description: my scan
        include: [{{file: {SCAN}}}]
        nodes: []
        """)
    plan = load_launch(wrapper, parse_overrides(["spacing_mm:=8", "speed_mm_s:=10.0"]), run_dir=tmp_path / "r")
    assert plan.node_params["scanner"]["spacing_mm"] == 8.0 and plan.node_params["scanner"]["speed_mm_s"] == 10.0
    assert plan.included_args == {"launch/scan_sim.yaml": ["spacing_mm", "speed_mm_s"]}
    assert load_launch(wrapper, {}, run_dir=tmp_path / "r").node_params["scanner"]["spacing_mm"] == 3.0
    with pytest.raises(LaunchError, match=r"unknown arg 'spacng_mm' given by the command line \(did you mean "
                                          r"'spacing_mm'\?\) \(no file declares it"):
        load_launch(wrapper, {"spacng_mm": 8}, run_dir=tmp_path / "r")


def test_it_reaches_every_depth_and_an_include_that_sets_the_arg_wins(tmp_path: Path) -> None:
    write(tmp_path / "inner.yaml", """\
        args: [{name: rate, default: 1.0}, {name: text, default: inner}]
        nodes: [{name: t, node: nodes.demo:Talker, params: {rate_hz: $(arg rate), text: $(arg text)}}]
        """)
    write(tmp_path / "middle.yaml", """\
        include: [{file: inner.yaml, args: {text: middle}}]
        nodes: []
        """)
    top = write(tmp_path / "top.yaml", """\
        args: [{name: text, default: top}]
        include: [{file: middle.yaml}]
        nodes: [{name: l, node: nodes.demo:Listener}]
        """)
    plan = load_launch(top, {"rate": 7.0, "text": "cli"}, run_dir=tmp_path / "r")
    # rate: declared two includes down, given by no include: the command line's; text: middle's include sets it
    assert plan.node_params["t"] == {"rate_hz": 7.0, "text": "middle", "count": 0}
    assert plan.args == {"text": "cli"}  # the top file's own arg took it
    lone = write(tmp_path / "lone.yaml", """\
        include: [{file: middle.yaml}]
        nodes: []
        """)
    with pytest.raises(LaunchError, match=r"arg 'text' given by the command line reaches no file: the include at "
                                          r".*middle.yaml:1:\d+ sets it itself"):
        load_launch(lone, {"text": "cli"}, run_dir=tmp_path / "r")


def test_a_missing_required_arg_of_an_included_file_can_come_from_the_command_line(tmp_path: Path) -> None:
    write(tmp_path / "needs.yaml", """\
        args: [{name: text}]
        nodes: [{name: t, node: nodes.demo:Talker, params: {text: $(arg text)}}]
        """)
    top = write(tmp_path / "top.yaml", "include: [{file: needs.yaml}]\nnodes: []\n")
    with pytest.raises(LaunchError, match="add text: VALUE to the include's args, or pass text:=VALUE"):
        load_launch(top, {}, run_dir=tmp_path / "r")
    assert load_launch(top, {"text": "hi"}, run_dir=tmp_path / "r").node_params["t"]["text"] == "hi"


def test_launch_check_says_which_included_args_the_command_line_set(tmp_path: Path) -> None:
    from palpa.cli.launch import describe

    wrapper = write(tmp_path / "my.yaml", f"include: [{{file: {SCAN}}}]\nnodes: []\n")
    text = describe(load_launch(wrapper, {"spacing_mm": 8}, run_dir=tmp_path / "r"))
    assert "args set in included files by the command line:\n  launch/scan_sim.yaml: [spacing_mm]" in text
