"""models.background: the surface under a map, fitted robustly, and the plane guard."""

from __future__ import annotations

import numpy as np
import pytest

from models.background import fit_background, raised_above_plane


def _noise_free() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A noise-free flat map at 10 (log) with a raised 4 x 4 patch at its centre: most cells fit any surface exactly,
    so the residuals' robust scale is rounding."""
    x = y = np.arange(20) * 2.0 + 1.0
    logs = np.full((20, 20), np.log(10.0))
    logs[8:12, 8:12] += 0.3
    return logs, x, y


@pytest.mark.parametrize("robust_start", [False, True])
@pytest.mark.parametrize("guard_snr", [0.0, 2.5])
def test_a_map_without_noise_has_the_level_of_the_cells_that_fit_it(robust_start: bool, guard_snr: float) -> None:
    """A scale at rounding is no noise: biweights scaled by it would all be zero and the next fit a surface of 0
    (a flat synthetic map then reported a baseline of 1). The surface is the flat level, not the least-squares one
    the patch lifts (which would read the patch as weaker), with or without a robust start and the guard."""
    logs, x, y = _noise_free()
    use = np.ones(logs.shape, dtype=bool)
    surface = fit_background(logs, use, x, y, robust_start=robust_start, guard_snr=guard_snr)
    assert surface == pytest.approx(np.full(logs.shape, np.log(10.0)), abs=1e-9)
    flat = fit_background(np.full(logs.shape, np.log(10.0)), use, x, y, robust_start=robust_start)
    assert flat == pytest.approx(np.full(logs.shape, np.log(10.0)), abs=1e-9)


def test_the_guard_on_a_map_without_noise_flags_the_patch_and_nothing_else() -> None:
    logs, x, y = _noise_free()
    raised = raised_above_plane(logs, np.ones(logs.shape, dtype=bool), x, y, 2.5)
    expected = np.zeros(logs.shape, dtype=bool)
    expected[8:12, 8:12] = True
    assert np.array_equal(raised, expected)
