"""The world's mechanics (models/world) against outside figures: an independent FE table and contact facts.

The reference figures are from issue 14 (axisymmetric FE by another solver, nu = 0.49, bonded layer,
frictionless sphere r = 4 mm, background 26.4 kPa): they go through the researcher's query
(``python -m models.world force``), so a wrong constant anywhere on that path fails here.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from models.phantom import load_phantom, parse_phantom
from models.world import TissueWorld, WorldRangeError
from models.world.__main__ import main as world_main

E_BG = 26.4


def _write(tmp_path: Path, name: str, **over: Any) -> Path:
    data: dict[str, Any] = {
        "size_mm": [60, 60],
        "thickness_mm": 3.68,
        "youngs_modulus_kpa": E_BG,
        "poisson_ratio": 0.49,
        "inclusions": [],
    }
    data.update(over)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _query(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, Any]:
    assert world_main(["force", *args]) == 0
    out: dict[str, Any] = json.loads(capsys.readouterr().out.strip())
    return out


# (inclusion radius mm, stiffness ratio, indentation mm, FE contrast from issue 14)
REFERENCE = [
    (6.0, 6.0, 1.0, 1.51),
    (6.0, 6.0, 1.41, 1.58),
    (5.0, 4.0, 1.0, 1.40),
    (4.0, 2.0, 1.0, 1.19),
    (4.0, 2.0, 1.41, 1.20),
    (3.0, 3.0, 1.0, 1.25),
]


@pytest.mark.parametrize(("radius", "ratio", "depth", "expected"), REFERENCE)
def test_reference_fe_contrasts_through_the_query(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    radius: float,
    ratio: float,
    depth: float,
    expected: float,
) -> None:
    inc = {
        "center_mm": [30, 30],
        "radius_mm": radius,
        "depth_mm": 2.0,
        "youngs_modulus_kpa": E_BG * ratio,
    }
    with_inc = _write(tmp_path, "inc", inclusions=[inc])
    plain = _write(tmp_path, "plain")
    f_inc = _query(capsys, str(with_inc), "--at", "30,30", "--depth", str(depth))["force_n"]
    f_plain = _query(capsys, str(plain), "--at", "30,30", "--depth", str(depth))["force_n"]
    assert f_inc / f_plain == pytest.approx(expected, rel=0.10)


def test_homogeneous_thick_layer_matches_the_reference_fe_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(tmp_path, "thick", thickness_mm=20.0)
    out = _query(capsys, str(path), "--at", "30,30", "--depth", "1.0", "--radius", "4")
    assert out["force_n"] == pytest.approx(0.1037, rel=0.05)
    assert out["thickness_mm"] == pytest.approx(20.0)


def test_force_scales_with_modulus_and_radius_squared_at_fixed_groups() -> None:
    base = TissueWorld(
        parse_phantom({"size_mm": [60, 60], "thickness_mm": 20, "youngs_modulus_kpa": 10.0})
    )
    stiff = TissueWorld(
        parse_phantom({"size_mm": [60, 60], "thickness_mm": 20, "youngs_modulus_kpa": 30.0})
    )
    big = TissueWorld(
        parse_phantom({"size_mm": [60, 60], "thickness_mm": 40, "youngs_modulus_kpa": 10.0})
    )
    f = float(base.force_n(30, 30, 1.0))
    assert float(stiff.force_n(30, 30, 1.0)) == pytest.approx(3 * f, rel=1e-9)
    # The same dimensionless case twice the size: force over E r^2 is unchanged.
    assert float(big.force_n(30, 30, 2.0, indenter_radius_mm=8.0)) == pytest.approx(4 * f, rel=1e-6)
    # Shallow contact is Hertzian: F ~ d^1.5 (the layer is 50 contact radii thick).
    lo, hi = (float(base.force_n(30, 30, d)) for d in (0.05, 0.1))
    assert hi / lo == pytest.approx(2**1.5, rel=0.03)
    # Below the tables' first depth (0.01 r) the force follows Hertz's exponent exactly.
    lo, hi = (float(base.force_n(30, 30, d)) for d in (0.01, 0.02))
    assert hi / lo == pytest.approx(2**1.5, rel=1e-9)


def test_the_query_answers_the_inverse_and_names_what_contributes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = str(Path(__file__).parents[1] / "phantoms" / "airfloat_tumours.yaml")
    out = _query(capsys, path, "--at", "17,18", "--depth", "1.0")
    assert out["thickness_mm"] == pytest.approx(3.68)
    assert out["inclusion_under_point"] == 0
    assert out["contrast"] > 1.2 and out["force_n"] == pytest.approx(
        out["homogeneous_force_n"] * out["contrast"]
    )
    assert [c["index"] for c in out["inclusions"]][0] == 0
    back = _query(capsys, path, "--at", "17,18", "--force", str(out["force_n"]))
    assert back["depth_mm"] == pytest.approx(1.0, rel=1e-6)


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.5])
def test_shallow_indentation_of_a_thick_layer_is_hertzian(nu: float) -> None:
    """48 mm under a 4 mm sphere at 0.02-0.4 mm is a half-space to 2 %: Hertz, with its 1 - nu^2."""
    world = TissueWorld(
        parse_phantom(
            {
                "size_mm": [200, 200],
                "thickness_mm": 48,
                "youngs_modulus_kpa": 10,
                "poisson_ratio": nu,
            }
        )
    )
    d = np.array([0.02, 0.08, 0.4])
    hertz = 4.0 / 3.0 * 10e-3 / (1.0 - nu**2) * np.sqrt(4.0) * d**1.5
    np.testing.assert_allclose(np.asarray(world.force_n(100, 100, d)), hertz, rtol=0.025)


@pytest.mark.system
def test_the_cli_runs_as_a_module(tmp_path: Path) -> None:
    path = _write(tmp_path, "cli", thickness_mm=20.0)
    done = subprocess.run(
        [sys.executable, "-m", "models.world", "force", str(path), "--at", "30,30", "--depth", "1"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 1 and json.loads(lines[0])["force_n"] > 0
    bad = subprocess.run(
        [sys.executable, "-m", "models.world", "force", str(path), "--at", "30,30", "--depth", "9"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert (
        bad.returncode == 1 and "beyond the tables" in bad.stderr and "Traceback" not in bad.stderr
    )


def _tumours() -> TissueWorld:
    return TissueWorld(
        load_phantom(Path(__file__).parents[1] / "phantoms" / "airfloat_tumours.yaml")
    )


def test_force_is_monotonic_in_depth_and_the_inverse_agrees() -> None:
    world = _tumours()
    depths = np.linspace(0.02, 1.5, 60)
    for x, y in [(15, 18), (30, 30), (21, 18), (45, 42), (5, 30)]:
        f = np.asarray(world.force_n(x, y, depths))
        assert np.all(np.diff(f) > 0), (x, y)
        back = np.asarray(world.depth_mm(x, y, f))
        np.testing.assert_allclose(back, depths, rtol=1e-3)
    assert world.force_n(30, 30, 0.0) == 0.0 and world.force_n(30, 30, -1.0) == 0.0
    assert world.depth_mm(30, 30, 0.0) == 0.0


def test_vector_queries_match_scalar_ones() -> None:
    world = _tumours()
    x, y = np.meshgrid(np.linspace(1, 59, 7), np.linspace(8, 52, 5))
    grid = np.asarray(world.force_n(x, y, 0.8))
    assert grid.shape == x.shape
    assert grid[2, 3] == pytest.approx(float(world.force_n(x[2, 3], y[2, 3], 0.8)), rel=1e-12)


def test_an_inclusion_is_felt_on_its_axis_and_fades_to_background_far_away() -> None:
    flat = {
        "size_mm": [80, 60],
        "thickness_mm": 5.0,
        "youngs_modulus_kpa": E_BG,
        "poisson_ratio": 0.5,
    }
    inc = {"center_mm": [20, 30], "radius_mm": 4, "depth_mm": 1.5, "youngs_modulus_kpa": 6 * E_BG}
    world = TissueWorld(parse_phantom(flat | {"inclusions": [inc]}))
    plain = TissueWorld(parse_phantom(flat))
    x = 20.0 + np.array([0.0, 2.0, 4.0, 6.0, 10.0, 20.0, 40.0, 55.0])  # 55: beyond the tables
    ratio = np.asarray(world.force_n(x, 30, 1.0)) / np.asarray(plain.force_n(x, 30, 1.0))
    assert ratio[0] > 1.3
    assert np.all(np.diff(ratio) <= 1e-12)  # never rises moving away
    assert ratio[3] < ratio[0] - 0.2  # 2 mm beyond the edge much is lost
    np.testing.assert_allclose(ratio[-3:], 1.0, atol=2e-3)
    # Radially symmetric about the inclusion's axis.
    assert float(world.force_n(20, 34, 1.0)) == pytest.approx(
        float(world.force_n(24, 30, 1.0)), rel=1e-9
    )


def test_a_short_inclusion_is_felt_less_than_one_down_to_the_table() -> None:
    flat = {
        "size_mm": [60, 60],
        "thickness_mm": 8.0,
        "youngs_modulus_kpa": E_BG,
        "poisson_ratio": 0.5,
    }
    inc = {"center_mm": [30, 30], "radius_mm": 4, "depth_mm": 1.0, "youngs_modulus_kpa": 4 * E_BG}
    full = float(TissueWorld(parse_phantom(flat | {"inclusions": [inc]})).force_n(30, 30, 1.0))
    short = float(
        TissueWorld(parse_phantom(flat | {"inclusions": [inc | {"height_mm": 1.0}]})).force_n(
            30, 30, 1.0
        )
    )
    plain = float(TissueWorld(parse_phantom(flat)).force_n(30, 30, 1.0))
    assert plain < short < full


def test_a_domed_top_is_used_at_the_local_thickness() -> None:
    domed = {
        "size_mm": [60, 60],
        "thickness_mm": {"center": 4, "edge": 2},
        "youngs_modulus_kpa": E_BG,
    }
    dome = TissueWorld(parse_phantom(domed))
    for y in (5.0, 18.0, 30.0):
        t = float(dome.phantom.thickness(30, y))
        flat = TissueWorld(
            parse_phantom({"size_mm": [60, 60], "thickness_mm": t, "youngs_modulus_kpa": E_BG})
        )
        assert float(dome.force_n(30, y, 1.0)) == pytest.approx(
            float(flat.force_n(30, 30, 1.0)), rel=1e-9
        )
    # Thinner (towards the edges) is stiffer at the same depth.
    assert float(dome.force_n(30, 5, 1.0)) > float(dome.force_n(30, 30, 1.0))


def test_out_of_table_inputs_are_clear_errors() -> None:
    world = _tumours()
    with pytest.raises(WorldRangeError, match=r"depth 3.5 mm at \(30.00, 30.00\).*at most"):
        world.force_n(30, 30, 3.5)  # 4 mm thick there: at most 0.75 t = 3 mm
    with pytest.raises(WorldRangeError, match="force 50 N"):
        world.depth_mm(30, 30, 50.0)
    with pytest.raises(WorldRangeError, match="below the tables"):
        world.force_n(30, 1, 0.5, indenter_radius_mm=10.0)  # 2 mm layer under a 10 mm sphere
    with pytest.raises(WorldRangeError, match="indenter_radius_mm"):
        world.force_n(30, 30, 0.5, indenter_radius_mm=0.0)
    with pytest.raises(WorldRangeError, match="poisson_ratio 0.2"):
        TissueWorld(
            parse_phantom(
                {
                    "size_mm": [9, 9],
                    "thickness_mm": 5,
                    "youngs_modulus_kpa": 9,
                    "poisson_ratio": 0.2,
                }
            )
        )
    soft = {"center_mm": [4, 4], "radius_mm": 2, "depth_mm": 1, "youngs_modulus_kpa": 1.0}
    with pytest.raises(WorldRangeError, match=r"inclusions\[0\] stiffness ratio"):
        TissueWorld(
            parse_phantom(
                {
                    "size_mm": [9, 9],
                    "thickness_mm": 5,
                    "youngs_modulus_kpa": 9,
                    "inclusions": [soft],
                }
            )
        )
    with pytest.raises(ValueError, match="spring sample"):
        TissueWorld(
            parse_phantom({"size_mm": [9, 9], "thickness_mm": 5, "spring_constant_n_per_mm": 0.3})
        )
    assert np.isnan(world.force_n(-5, 30, 1.0)) and np.isnan(world.depth_mm(70, 30, 0.1))
