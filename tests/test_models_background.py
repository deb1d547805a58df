"""models.background: the surface under a map, fitted robustly."""

from __future__ import annotations

import numpy as np
import pytest

from models.background import fit_background


def test_a_robust_fit_of_a_map_without_noise_is_the_surface_through_the_cells_that_fit_it() -> None:
    """A partial map's fit (``robust_start``) on a noise-free flat map with a raised patch at its centre: most cells
    fit exactly, so the robust scale is zero, and the least-squares plane through all the cells is the flat level
    lifted by the patch, every healthy cell's residual the same (a zero scale again). The surface is the level of
    the cells that fit, not that lifted plane (which would read the patch as weaker); a whole map's fit is left as
    it always was."""
    x = y = np.arange(20) * 2.0 + 1.0
    logs = np.full((20, 20), np.log(10.0))
    logs[8:12, 8:12] += 0.3
    use = np.ones(logs.shape, dtype=bool)
    for degree in (1, 2):
        surface = fit_background(logs, use, x, y, robust_start=True, degree=degree)
        assert surface == pytest.approx(np.full(logs.shape, np.log(10.0)), abs=1e-9), degree
    lifted = fit_background(logs, use, x, y, degree=1)   # least squares from the start: the patch lifts it
    assert float(np.max(lifted)) > np.log(10.0) + 1e-3
