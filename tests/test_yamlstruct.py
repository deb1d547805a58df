"""The one YAML loader: file:line:col errors for launch files, parameter files and calibrations alike."""

from __future__ import annotations

import re
from pathlib import Path

import msgspec
import pytest

from nodes.demo import Talker
from palpa.errors import ParamError
from palpa.node.params import parse_param_value, read_params_file
from palpa.node.runner import run_node_code
from yamlstruct import YamlError, load


class Point(msgspec.Struct, forbid_unknown_fields=True):
    x: float
    y: float = 0.0


class Doc(msgspec.Struct, forbid_unknown_fields=True):
    points: list[Point]


def test_a_struct_loads_and_errors_name_the_line(tmp_path: Path) -> None:
    f = tmp_path / "d.yaml"
    f.write_text("points:\n  - {x: 1e-3}\n  - {x: 2, yy: 3}\n")
    with pytest.raises(YamlError, match=r"d.yaml:3:\d+: unknown key 'yy' in points\[1\] \(did you mean 'y'\?\)"):
        load(f, Doc)
    f.write_text("points:\n  - {x: 1e-3}\n  - {x: two}\n")
    with pytest.raises(YamlError, match=r"d.yaml:3:\d+: points\[1\].x: expected `float`, got `str`"):
        load(f, Doc)
    f.write_text("points:\n  - {x: 1e-3}\n")
    doc, _ = load(f, Doc)
    assert doc == Doc([Point(1e-3)])


def test_duplicate_keys_and_bad_yaml_are_refused_with_their_line(tmp_path: Path) -> None:
    f = tmp_path / "d.yaml"
    f.write_text("points: []\npoints: []\n")
    with pytest.raises(YamlError, match=r"d.yaml:2:1: duplicate key 'points' \(first at line 1\)"):
        load(f, Doc)
    f.write_text("points: [\n")
    with pytest.raises(YamlError, match=r"d.yaml:2:\d+: invalid YAML"):
        load(f, Doc)


def test_parameter_files_go_through_it(tmp_path: Path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text("rate_hz: 5\nrate_hz: 6\n")
    with pytest.raises(ParamError, match=r"--params-file p: .*p.yaml:2:1: duplicate key 'rate_hz'"):
        read_params_file(f, "--params-file p")
    f.write_text("- 1\n")
    with pytest.raises(ParamError, match=r"p.yaml:1:1: expected a mapping of parameters"):
        read_params_file(f, "p")
    f.write_text("rate_hz: 1e3\nname: yes\n")
    assert read_params_file(f, "p") == {"rate_hz": 1000.0, "name": "yes"}  # YAML 1.2: yes is a string


def test_a_params_file_is_checked_against_the_node_at_file_line(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "p.yaml"
    f.write_text("text: hi\nrte_hz: 5\n")
    with pytest.raises(ParamError, match=r"^p: .*p.yaml:2:1: node class Talker has no parameter 'rte_hz' "
                                         r"\(did you mean 'rate_hz'\?\); declared: rate_hz, text, count$"):
        read_params_file(f, "p", Talker.Params)
    f.write_text("text: hi\nrate_hz: fast\n")
    with pytest.raises(ParamError, match=r"p.yaml:2:10: rate_hz: expected `float`, got `str`$"):
        read_params_file(f, "p", Talker.Params)
    f.write_text("rate_hz: -1\n")
    with pytest.raises(ParamError, match=r"p.yaml:1:10: rate_hz: expected `float` > 0.0, got -1$"):
        read_params_file(f, "p", Talker.Params)
    f.write_text("rate_hz: 5\n")
    assert read_params_file(f, "p", Talker.Params) == {"rate_hz": 5}  # a file may give only some of them
    # palpa run: the node's class checks the file before any socket opens, one line naming node and file:line
    f.write_text("text: hi\nrate_hz: fast\n")
    assert run_node_code(Talker, ["--params-file", str(f)]) == 2
    assert re.search(r"^Talker: --params-file .*p.yaml: .*p.yaml:2:10: rate_hz: expected `float`, got `str`$",
                     capsys.readouterr().err.strip())


def test_command_line_values_are_read_as_yaml_1_2() -> None:
    assert parse_param_value("yes", "-p a") == "yes"
    assert parse_param_value("[1, 2.5]", "-p a") == [1, 2.5]
    assert parse_param_value("", "-p a") == ""
    with pytest.raises(ParamError, match=r"^-p a:1:\d+: invalid YAML"):
        parse_param_value("[1, 2", "-p a")


def test_the_airfloat_calibration_goes_through_it(tmp_path: Path) -> None:
    from models.calibration_airfloat import CalibrationError, load_calibration

    f = tmp_path / "cal.yaml"
    f.write_text("force: {gain: 8.0, offset: -2.5}\ndepth_offset_mm: 0.1\n")
    cal = load_calibration(f)
    assert (cal.force.gain, cal.force.offset, cal.force.pressure_unit_kpa, cal.depth_offset_mm) == (8.0, -2.5, 100.0,
                                                                                                    0.1)
    cases = {
        "force: {gain: 8, offset: .inf}\n": r"cal.yaml:1:26: force.offset: expected a finite `float`, got inf$",
        "force: {gain: 8, offset: 1}\nfource: 2\n": r"cal.yaml:2:1: unknown key 'fource' in the calibration file "
                                                    r"\(did you mean 'force'\?\)",
        "force: {gain: 0, offset: 1}\n": r"cal.yaml:1:8: force: ForceCalibration: gain must be finite and > 0",
        "depth_offset_mm: 0.1\n": r"cal.yaml:1:1: the calibration file is missing the required key 'force'",
    }
    for text, match in cases.items():
        f.write_text(text)
        with pytest.raises(CalibrationError, match=match):
            load_calibration(f)
