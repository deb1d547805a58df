"""Fits of the camera-probe calibration (models/camera_calibration.py) on synthetic rig records with a known
answer: a distorted per-marker scale, friction and filter lag that flip with the direction of motion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.camera_calibration import (
    CalibrationError,
    ProbeCalibration,
    fit_scale,
    fit_springs,
    load_probe_calibration,
)


def ramp(top: float = 9.0, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    t = np.concatenate([np.linspace(0, top, n), np.linspace(top, 0, n)])
    return t, np.concatenate([np.ones(n), -np.ones(n)])


def test_rigid_flat_gives_each_markers_own_pixel_map() -> None:
    t, d = ramp()
    rng = np.random.default_rng(1)
    dx = np.clip(t - 1.5, 0, None)  # contact after 1.5 mm of travel
    scale = np.array([12.2, 12.9, 12.5, 13.0])
    u = scale * dx[:, None] * (1 - 0.0015 * dx[:, None]) - 0.4 * d[:, None] + rng.normal(0, 0.05, (t.size, 4))
    polys, contact = fit_scale(t, u, d)
    cal = ProbeCalibration(polys, (0.05,) * 4)
    clean = scale * np.linspace(1, 7, 20)[:, None] * (1 - 0.0015 * np.linspace(1, 7, 20)[:, None])
    np.testing.assert_allclose(cal.to_mm(clean), np.repeat(np.linspace(1, 7, 20)[:, None], 4, 1), atol=0.004)
    np.testing.assert_allclose(contact, 1.5, atol=0.01)


def test_reference_spring_slope_gives_the_spring_constant() -> None:
    t, d = ramp(12.0)
    k_true = np.array([0.052, 0.24, 0.047, 0.05])
    k_ref, friction = 0.1, 0.006
    dx = np.clip((k_ref * (t[:, None] - 2.0) - friction * d[:, None]) / (k_true + k_ref), 0, None)
    dx += np.random.default_rng(2).normal(0, 0.006, dx.shape)
    k, se = fit_springs(t, dx, d, k_ref)
    np.testing.assert_allclose(k, k_true, rtol=0.004)
    assert np.all(se > 0) and np.all(se < 0.01 * k_true)


def test_a_press_without_release_is_refused() -> None:
    t = np.linspace(0, 9, 300)
    with pytest.raises(CalibrationError, match="marker 1"):
        fit_scale(t, np.repeat(t[:, None] * 12.7, 4, 1), np.ones_like(t))
    with pytest.raises(CalibrationError, match=r"^cal.yaml: unknown key .spring. in the calibration file"):
        ProbeCalibration.from_dict({"scale_poly": [[0.08]], "k_n_per_mm": [0.05], "spring": 1}, "cal.yaml")


def test_the_file_loads_through_yamlstruct_with_lines(tmp_path: Path) -> None:
    good = load_probe_calibration("tests/data/camera_probe6.yaml")
    assert len(good.k_n_per_mm) == 4 and good.direction == 1.0
    f = tmp_path / "cal.yaml"
    f.write_text("scale_poly: [[0.08], [0.08]]\nk_n_per_mm: [0.05, -0.2]\n")
    with pytest.raises(CalibrationError, match=r"cal.yaml:2:13: spring constants must be finite and > 0"):
        load_probe_calibration(f)
    f.write_text("scale_poly: [[0.08]]\nk_n_per_mm: [0.05]\ndirection: yes\n")  # YAML 1.2: a string, not true
    with pytest.raises(CalibrationError, match=r"cal.yaml:3:12: direction: expected `float`, got `str`"):
        load_probe_calibration(f)
