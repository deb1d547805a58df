"""The shipped world tables against fresh scikit-fem solves (coarse meshes, a few seconds).

Each case sits on a table node, so the comparison checks the solves behind the table (and that the
table was built by this solver with these grids), not the interpolation; test_world.py checks the
interpolated world against the independent reference figures.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("skfem")

from models.world.fe import AxisymmetricContact, Layer  # noqa: E402
from models.world.tables import TABLE_PATH  # noqa: E402

COARSE = 0.06  # axis spacing over r; the tables use 0.02 (homogeneous) and 0.03 (inclusions)


@pytest.fixture(scope="module")
def tables() -> dict[str, np.ndarray]:
    with np.load(TABLE_PATH) as z:
        return {k: z[k] for k in z.files}


def _node(axis: np.ndarray, value: float) -> int:
    i = int(np.argmin(np.abs(axis - value)))
    assert axis[i] == pytest.approx(value), f"{value} is not a node of {axis}"
    return i


@pytest.mark.parametrize(("nu", "t", "d"), [(0.49, 1.0, 0.2), (0.5, 5.0, 0.5)])
def test_homogeneous_force_table_matches_a_fresh_solve(
    tables: dict[str, np.ndarray], nu: float, t: float, d: float
) -> None:
    d = float(tables["hom_d"][np.argmin(np.abs(tables["hom_d"] - d))])
    shipped = tables["hom_force"][
        _node(tables["hom_nu"], nu), _node(tables["hom_t"], t), _node(tables["hom_d"], d)
    ]
    fresh = AxisymmetricContact(Layer(t, nu), fine=COARSE).force(d)
    assert fresh == pytest.approx(shipped, rel=0.02)


def test_inclusion_contrast_table_matches_a_fresh_solve(tables: dict[str, np.ndarray]) -> None:
    nu, t, s, rad, k = 0.49, 1.0, 0.35, 1.0, 4.0
    idx = (
        _node(tables["c_nu"], nu), _node(tables["c_t"], t), slice(None),
        _node(tables["c_s"], s), _node(tables["c_r"], rad), _node(tables["c_k"], k),
    )  # fmt: skip
    shipped = tables["contrast"][idx]
    depths = tables["c_d"][[1, 3]]
    plain = AxisymmetricContact(Layer(t, nu), fine=COARSE)
    stiff = AxisymmetricContact(Layer(t, nu, rad, s * t, None, k), fine=COARSE)
    fresh = [stiff.force(float(d)) / plain.force(float(d)) for d in depths]
    np.testing.assert_allclose(fresh, shipped[[1, 3]], rtol=0.02)
    assert min(fresh) > 1.1  # a real inclusion, not a trivially matching 1.0


def test_the_world_reproduces_a_fresh_solve_through_its_public_query() -> None:
    """A case on table nodes (nu 0.49, t = r, top 0.35 t, R = r, x4, d = 0.2 r) with r = 4 mm:
    the interpolated world's excess force (contrast - 1) against fresh coarse FE, to 4 %."""
    from models.phantom import parse_phantom
    from models.world import TissueWorld

    base = {
        "size_mm": [60, 60],
        "thickness_mm": 4.0,
        "youngs_modulus_kpa": 20.0,
        "poisson_ratio": 0.49,
    }
    inc = {"center_mm": [30, 30], "radius_mm": 4.0, "depth_mm": 1.4, "youngs_modulus_kpa": 80.0}
    world = TissueWorld(parse_phantom(base | {"inclusions": [inc]}))
    plain = TissueWorld(parse_phantom(base))
    excess = float(world.force_n(30, 30, 0.8)) / float(plain.force_n(30, 30, 0.8)) - 1.0
    fresh = (
        AxisymmetricContact(Layer(1.0, 0.49, 1.0, 0.35, None, 4.0), fine=COARSE).force(0.2)
        / AxisymmetricContact(Layer(1.0, 0.49), fine=COARSE).force(0.2)
        - 1.0
    )
    assert excess == pytest.approx(fresh, rel=0.04)
