"""Multi-indenter probe (paper 2, eq. 5): forward model, exact / LM / batch inverse, Table I."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.multi_indenter import (
    CENTROID_NOISE_PX,
    PAPER_GEOMETRY,
    PX_PER_MM,
    ProbeGeometry,
    advance_range_mm,
    forward,
)
from models.multi_indenter_batch import solve_batch
from models.multi_indenter_solve import (
    REASONS,
    StiffnessSolution,
    solve_exact,
    solve_lm,
)

G = PAPER_GEOMETRY
DEG = math.pi / 180


def eq5_residuals(geom: ProbeGeometry, dx: np.ndarray, sol: StiffnessSolution) -> np.ndarray:
    """The paper's F(x) of eq. 5, written out row by row (indenter 1 is the reference)."""
    k, kt, dt = geom.k_n_per_mm, sol.k_t_n_per_mm, sol.dt_mm
    th, al = sol.pan_rad, sol.tilt_rad
    rows = [dx[i] * k[i] - kt * dt[i] for i in range(4)]
    for j in (1, 2, 3):
        d_x = geom.x_mm[j] - geom.x_mm[0]
        d_y = geom.y_mm[j] - geom.y_mm[0]
        rows.append(dx[j] + dt[j] - dx[0] - dt[0] + math.tan(th) * d_x + math.tan(al) * d_y)
    return np.asarray(rows)


def random_poses(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    kt = np.exp(rng.uniform(math.log(0.03), math.log(3.0), n))
    pan = rng.uniform(-20, 20, n) * DEG
    tilt = rng.uniform(-20, 20, n) * DEG
    adv = rng.uniform(6.5, 9.5, n)
    return kt, adv, pan, tilt


# ---------------------------------------------------------------- geometry and forward model


def test_paper_geometry_numbering_and_layout() -> None:
    assert G.k_n_per_mm == (0.05, 0.25, 0.05, 0.05)  # indenter 2 (index 1) is the hard one
    assert (G.x_mm[1], G.y_mm[1]) == (0.0, 0.0)
    radii = [math.hypot(G.x_mm[i], G.y_mm[i]) for i in (0, 2, 3)]
    np.testing.assert_allclose(radii, 8.0)
    angles = sorted(math.degrees(math.atan2(G.y_mm[i], G.x_mm[i])) % 360 for i in (0, 2, 3))
    gaps = np.diff([*angles, angles[0] + 360])
    np.testing.assert_allclose(sorted(gaps), [102.0, 102.0, 156.0])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"x_mm": (0, 1, 2), "y_mm": (0, 1, 2), "k_n_per_mm": (1, 1, 1)},
        {"x_mm": (0, 1, 2, 3), "y_mm": (0, 1, 2), "k_n_per_mm": (1, 1, 1, 1)},
        {"x_mm": (0, 1, 2, 3), "y_mm": (0, 1, 2, 3), "k_n_per_mm": (1, 0, 1, 1)},
        {"x_mm": (0, 1, 2, math.nan), "y_mm": (0, 1, 2, 3), "k_n_per_mm": (1, 1, 1, 1)},
        {"x_mm": (0, 1, 2, 3), "y_mm": (0, 1, 2, 3), "k_n_per_mm": (1, 1, 1, 1), "stroke_mm": 0},
    ],
)
def test_geometry_rejects_bad_values(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="ProbeGeometry"):
        ProbeGeometry(**kwargs)  # type: ignore[arg-type]


def test_forward_flat_is_springs_in_series() -> None:
    c = forward(G, 0.4, 8.0)
    k = np.asarray(G.k_n_per_mm)
    np.testing.assert_allclose(c.dx_mm, 8.0 * 0.4 / (k + 0.4), rtol=1e-14)
    np.testing.assert_allclose(c.dx_mm + c.dt_mm, 8.0, rtol=1e-14)
    np.testing.assert_allclose(k * c.dx_mm, 0.4 * c.dt_mm, rtol=1e-13)
    assert c.contact.all() and not c.saturated.any()


def test_forward_tilt_satisfies_eq5_and_first_contact_has_full_advance() -> None:
    c = forward(G, 0.3, 7.0, 12 * DEG, -8 * DEG)
    overlap = c.dx_mm + c.dt_mm
    assert overlap.max() == pytest.approx(7.0)
    sol = StiffnessSolution(True, "ok", 0.3, 12 * DEG, -8 * DEG, tuple(c.dt_mm), 1.0)
    np.testing.assert_allclose(eq5_residuals(G, c.dx_mm, sol), 0.0, atol=1e-12)


def test_forward_partial_contact_and_saturation() -> None:
    # Tilted 20° about x: the +y indenter (1) is 8 tan 20° = 2.9 mm farther than the lowest.
    c = forward(G, 0.3, 1.0, 0.0, 20 * DEG)
    assert c.contact.tolist() == [False, True, True, True]
    assert c.dx_mm[0] == 0.0 and c.dt_mm[0] == 0.0
    none = forward(G, 0.3, -0.5)
    assert not none.contact.any() and not none.dx_mm.any() and not none.dt_mm.any()
    # The paper's 18 mm press drives the soft indenters past a 10 mm stroke.
    deep = forward(G, 0.29, 18.0)
    assert deep.saturated.tolist() == [True, False, True, True]
    assert deep.dx_mm.max() == G.stroke_mm
    np.testing.assert_allclose(deep.dx_mm + deep.dt_mm, 18.0)
    assert not solve_exact(deep.dx_mm).valid


@pytest.mark.parametrize(
    ("k", "pan", "tilt"), [(0.63, 0.0, 0.0), (0.29, 15.0, 0.0), (0.4, -9.0, 12.0)]
)
def test_advance_range_brackets_contact_and_stroke(k: float, pan: float, tilt: float) -> None:
    lo, hi = advance_range_mm(G, k, pan * DEG, tilt * DEG)
    assert lo < hi
    for adv, touching, saturated in ((lo - 1e-6, False, False), (lo + 1e-6, True, False),
                                     (hi - 1e-6, True, False), (hi + 1e-6, True, True)):  # fmt: skip
        c = forward(G, k, adv, pan * DEG, tilt * DEG)
        assert c.contact.all() == touching and c.saturated.any() == saturated
    assert advance_range_mm(G, 0.63)[1] == pytest.approx(10 * 0.68 / 0.63)  # < the paper's 18 mm


def test_forward_broadcasts() -> None:
    c = forward(G, np.array([0.2, 0.5, 1.0]), 8.0, np.array([[0.0], [0.1]]))
    assert c.dx_mm.shape == (2, 3, 4)
    np.testing.assert_allclose(c.dx_mm[1, 2], forward(G, 1.0, 8.0, 0.1).dx_mm)


@pytest.mark.parametrize(
    ("args", "match"),
    [((0.0, 5.0), "k_t"), ((0.3, math.nan), "advance"), ((0.3, 5.0, math.pi / 2), "pan")],
)
def test_forward_rejects_bad_inputs(args: tuple[float, ...], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        forward(G, *args)


# ---------------------------------------------------------------------------- inverse


def test_exact_and_lm_recover_noise_free_truth_and_agree() -> None:
    kt, adv, pan, tilt = random_poses(60, seed=3)
    c = forward(G, kt, adv, pan, tilt)
    usable = c.contact.all(axis=1) & ~c.saturated.any(axis=1)
    assert usable.sum() >= 40
    for i in np.flatnonzero(usable):
        ex = solve_exact(c.dx_mm[i])
        lm = solve_lm(c.dx_mm[i])
        assert ex.valid and lm.valid, (ex.reason, lm.reason)
        assert ex.k_t_n_per_mm == pytest.approx(kt[i], rel=1e-11)
        assert ex.pan_rad == pytest.approx(pan[i], abs=1e-11)
        assert ex.tilt_rad == pytest.approx(tilt[i], abs=1e-11)
        np.testing.assert_allclose(ex.dt_mm, c.dt_mm[i], atol=1e-11)
        assert abs(lm.k_t_n_per_mm - ex.k_t_n_per_mm) <= 1e-9 * ex.k_t_n_per_mm
        assert abs(lm.pan_rad - ex.pan_rad) <= 1e-9 and abs(lm.tilt_rad - ex.tilt_rad) <= 1e-9
        np.testing.assert_allclose(lm.dt_mm, ex.dt_mm, atol=1e-9)
        np.testing.assert_allclose(eq5_residuals(G, c.dx_mm[i], ex), 0.0, atol=1e-12)


def test_exact_and_lm_agree_on_noisy_data() -> None:
    # Eq. 5 is square (7 x 7): noisy displacements still have one exact solution.
    rng = np.random.default_rng(5)
    c = forward(G, 0.45, 8.0, 9 * DEG, -4 * DEG)
    for dx in c.dx_mm + rng.normal(0, 0.05, (15, 4)):
        ex, lm = solve_exact(dx), solve_lm(dx)
        assert ex.valid and lm.valid
        assert abs(lm.k_t_n_per_mm - ex.k_t_n_per_mm) <= 1e-9 * ex.k_t_n_per_mm
        assert abs(lm.pan_rad - ex.pan_rad) <= 1e-9


def _degenerate_cases() -> list[tuple[list[float], int]]:
    flat = forward(G, 0.4, 8.0).dx_mm.tolist()
    return [
        ([0.0, 0.0, 0.0, 0.0], 2),  # no contact
        ([flat[0], flat[1], 0.01, flat[3]], 2),  # one indenter off the surface
        ([flat[0], math.nan, flat[2], flat[3]], 1),  # lost marker
        ([flat[0], flat[1], math.inf, flat[3]], 1),
        ([flat[0], 10.0, flat[2], flat[3]], 3),  # end of stroke
        ([5.0, 5.0, 5.0, 5.0], 4),  # rigid surface
        ([5.0, 5.0 + 1e-12, 5.0, 5.0], 4),
        ([4.0, 6.0, 4.0, 4.0], 6),  # hard indenter moved more than the soft ones: K_t < 0
    ]


@pytest.mark.parametrize(("dx", "code"), _degenerate_cases())
def test_degenerate_inputs_give_invalid_results_with_reason(dx: list[float], code: int) -> None:
    for solver in (solve_exact, solve_lm):
        sol = solver(dx)
        assert not sol.valid
        assert sol.reason.startswith(REASONS[code]), sol.reason
        assert math.isnan(sol.k_t_n_per_mm) and all(math.isnan(v) for v in sol.dt_mm)
    batch = solve_batch([dx])
    assert not batch.valid[0] and batch.reason_code[0] == code


def test_equal_springs_make_the_system_singular() -> None:
    same = ProbeGeometry(G.x_mm, G.y_mm, (0.05,) * 4)
    dx = forward(same, 0.4, 8.0, 5 * DEG, 3 * DEG).dx_mm
    sol = solve_exact(dx, same)
    assert not sol.valid and sol.reason.startswith(REASONS[5]), sol.reason
    assert sol.condition > 1e4
    assert solve_batch(dx[None], same).reason_code[0] == 5


def test_wrong_length_is_a_caller_error() -> None:
    with pytest.raises(ValueError, match="expected 4 displacements"):
        solve_exact([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        solve_batch(np.zeros((3, 5)))


def test_batch_matches_single_solve_exactly() -> None:
    kt, adv, pan, tilt = random_poses(400, seed=11)
    dx = forward(G, kt, adv, pan, tilt).dx_mm
    dx += np.random.default_rng(12).normal(0, 0.02, dx.shape)
    bad = np.array([case for case, _ in _degenerate_cases()])
    dx = np.concatenate([dx, bad])
    batch = solve_batch(dx)
    assert 50 < batch.valid.sum() < len(dx)
    for i, row in enumerate(dx):
        one = solve_exact(row)
        assert one.valid == batch.valid[i]
        assert one.reason.startswith(batch.reason(i))
        # Same kernel, same floats: bit-identical stiffness and tissue displacements.
        assert (one.k_t_n_per_mm == batch.k_t_n_per_mm[i]) or (
            math.isnan(one.k_t_n_per_mm) and math.isnan(batch.k_t_n_per_mm[i])
        )
        np.testing.assert_array_equal(one.dt_mm, batch.dt_mm[i])
        np.testing.assert_allclose(
            [one.pan_rad, one.tilt_rad, one.condition],
            [batch.pan_rad[i], batch.tilt_rad[i], batch.condition[i]],
            rtol=1e-15,
            atol=0,
        )


# ------------------------------------------------------------ more indenters than needed


def _six_indenter_probe() -> ProbeGeometry:
    ang = np.radians([90, 150, 210, 270, 330])
    xs = (0.0, *(7.0 * np.cos(ang)).tolist())
    ys = (0.0, *(7.0 * np.sin(ang)).tolist())
    return ProbeGeometry(xs, ys, (0.25, 0.05, 0.08, 0.05, 0.08, 0.05))


def test_overdetermined_probe_uses_least_squares() -> None:
    six = _six_indenter_probe()
    c = forward(six, 0.7, 6.0, -7 * DEG, 11 * DEG)
    sol = solve_exact(c.dx_mm, six)
    assert sol.valid
    assert sol.k_t_n_per_mm == pytest.approx(0.7, rel=1e-12)
    assert (sol.pan_rad, sol.tilt_rad) == pytest.approx((-7 * DEG, 11 * DEG), abs=1e-12)
    lm = solve_lm(c.dx_mm, six)
    assert lm.valid and lm.k_t_n_per_mm == pytest.approx(0.7, rel=1e-9)
    # With noise the answer is the least-squares fit of the symmetric system.
    noisy = c.dx_mm + np.random.default_rng(2).normal(0, 0.03, 6)
    ls = solve_exact(noisy, six)
    mat = np.column_stack(
        [
            np.ones(6),
            -np.asarray(six.k_n_per_mm) * noisy,
            -np.asarray(six.x_mm),
            -np.asarray(six.y_mm),
        ]
    )
    z = np.linalg.lstsq(mat, noisy, rcond=None)[0]
    assert ls.k_t_n_per_mm == pytest.approx(1 / z[1], rel=1e-10)
    assert ls.pan_rad == pytest.approx(math.atan(z[2]), abs=1e-10)


def test_overdetermined_batch_agrees_and_handles_partial_contact() -> None:
    six = _six_indenter_probe()
    rng = np.random.default_rng(8)
    kt = rng.uniform(0.1, 2.0, 300)
    # Small advances on steep tilts leave 1-3 indenters off the surface.
    c = forward(
        six,
        kt,
        rng.uniform(0.5, 6.0, 300),
        rng.uniform(-25, 25, 300) * DEG,
        rng.uniform(-25, 25, 300) * DEG,
    )
    dx = c.dx_mm + rng.normal(0, 0.01, c.dx_mm.shape) * c.contact
    batch = solve_batch(dx, six)
    n_contact = (dx > 0.05).sum(axis=1)
    assert {4, 5, 6} <= set(n_contact[batch.valid].tolist())
    assert (batch.reason_code[n_contact < 4] == 2).all()
    for i, row in enumerate(dx):
        one = solve_exact(row, six)
        assert one.valid == batch.valid[i], (i, one.reason, batch.reason(i))
        if one.valid:
            assert one.k_t_n_per_mm == pytest.approx(batch.k_t_n_per_mm[i], rel=1e-12)
            assert one.tilt_rad == pytest.approx(batch.tilt_rad[i], abs=1e-12)
            np.testing.assert_allclose(one.dt_mm, batch.dt_mm[i], rtol=1e-12, atol=1e-15)


# ----------------------------------------------------------------------- paper, Table I

TABLE_I_SPRINGS = (0.29, 0.37, 0.62, 0.63)
# (pan, tilt) in degrees, up to 15°.
POSES = ((0.0, 0.0), (15.0, 0.0), (0.0, -15.0), (10.6, 10.6), (-12.0, 9.0))
ADVANCE_MM = 10.0  # the paper's 18 mm would saturate the soft indenters (see above)


def test_table_i_accuracy_with_pixel_noise(capsys: pytest.CaptureFixture[str]) -> None:
    """Table I, simulated: 300 frames per run, raw centroid noise 0.3 px at 12.7 px/mm.

    The tracker's Kalman filter would cut the noise to ~0.08 px; we leave it out
    (conservative). Accuracy as in the paper: 100 (1 - |mean K - K| / K).
    """
    rng = np.random.default_rng(2024)
    sigma_mm = CENTROID_NOISE_PX / PX_PER_MM
    lines = ["   K    pan   tilt    mean K      sd     RMSE  accuracy%  pan err  tilt err"]
    worst = 100.0
    for k in TABLE_I_SPRINGS:
        for pan_deg, tilt_deg in POSES:
            c = forward(G, k, ADVANCE_MM, pan_deg * DEG, tilt_deg * DEG)
            assert c.contact.all() and not c.saturated.any()
            dx = c.dx_mm + rng.normal(0, sigma_mm, (300, 4))
            b = solve_batch(dx)
            assert b.valid.all()
            est = b.k_t_n_per_mm
            acc = 100 * (1 - abs(est.mean() - k) / k)
            rmse = float(np.sqrt(np.mean((est - k) ** 2)))
            pan_err = abs(np.degrees(b.pan_rad.mean()) - pan_deg)
            tilt_err = abs(np.degrees(b.tilt_rad.mean()) - tilt_deg)
            lines.append(
                f"{k:5.2f} {pan_deg:6.1f} {tilt_deg:6.1f} {est.mean():9.4f} {est.std():7.4f} "
                f"{rmse:8.4f} {acc:9.3f} {pan_err:8.3f} {tilt_err:9.3f}"
            )
            worst = min(worst, acc)
            assert acc >= 99.0
            assert pan_err <= 1.0 and tilt_err <= 1.0
            lm = [solve_lm(row).k_t_n_per_mm for row in dx[:5]]
            np.testing.assert_allclose(lm, est[:5], rtol=1e-9)
    with capsys.disabled():
        print(
            "\nTable I (simulated, exact solve)\n"
            + "\n".join(lines)
            + f"\nworst accuracy {worst:.3f} %"
        )
