"""Which way a probe's sweep runs (nodes.scanner.scan_control.sweep_ends): up a sloped surface, whatever the arm's
position, because the simulated air-float probe (as the device: bore friction) reads a thinning layer softer than a
thickening one; on a level one from the end nearer the arm."""

from __future__ import annotations

import numpy as np
import pytest

from messages import ProbeAt
from models.airfloat import indentation_from_heights
from models.airfloat_device import ProbeErrors
from models.phantom import load_phantom
from models.surface import SurfaceFit, flat_surface
from nodes.drivers.fibre_sim import SimFibreDriver
from nodes.scanner.robot_scanner import RobotScanner
from nodes.scanner.scan_control import sweep_ends
from palpa.testing import NodeHarness
from tests.test_robot_scanner import SMALL

DOME = "phantoms/blank/dome_4_2.yaml"
LINE = (24.0, 47.0, 24.0, 53.0)
"""The coarse lattice's sweep at (24, 50) mm on the 4-2 mm dome, where two blank maps called a detection."""


def slope(dz_dy: float) -> SurfaceFit:
    """A plane rising ``dz_dy`` mm per mm along y."""
    return SurfaceFit((3.0, 0.0, dz_dy), (30.0, 30.0), "plane", 0.0, 3)


@pytest.mark.parametrize("here", [(24.0, 54.0), (24.0, 46.0), (16.0, 51.0), (32.0, 45.0)])
def test_a_sloped_line_is_swept_uphill_wherever_the_arm_is(here: tuple[float, float]) -> None:
    assert sweep_ends(LINE, here, slope(-0.09), 0.05) == (24.0, 53.0, 24.0, 47.0)   # the dome's far edge: up is -y
    assert sweep_ends(LINE, here, slope(0.09), 0.05) == LINE


def test_a_level_line_starts_at_the_end_nearer_the_arm() -> None:
    for surface in (None, flat_surface(3.0), slope(0.005)):   # 0.03 mm over 6 mm: below the 0.05 mm rise
        assert sweep_ends(LINE, (24.0, 54.0), surface, 0.05) == (24.0, 53.0, 24.0, 47.0)
        assert sweep_ends(LINE, (24.0, 46.0), surface, 0.05) == LINE
    assert sweep_ends(LINE, (24.0, 46.0), slope(-0.09), 1.0) == LINE   # climb_mm above the line's rise: off


def test_the_scanner_plans_a_probe_sweep_uphill() -> None:
    """The scanner's own plan for ``scanner/probe_at``: its slide starts at the line's lower end (y 53), though the
    arm is nearer the upper one (y 47); with ``sweep_climb_mm`` above the line's rise, at the nearer end."""
    h = NodeHarness(RobotScanner, {**SMALL, "autostart": False, "region_mm": [10, 40, 40, 56],
                                   "home_mm": [24, 44, 20]})
    h.node.specimen.surface = slope(-0.09)
    plan = h.node.control._plan(ProbeAt(x_mm=24.0, y_mm=50.0))
    slide = [w for w in plan.waypoints if abs(w.x_mm - 24.0) < 1e-9 and 46.9 < w.y_mm < 53.1]
    assert slide[0].y_mm == pytest.approx(53.0) and slide[-1].y_mm == pytest.approx(47.0)
    h = NodeHarness(RobotScanner, {**SMALL, "autostart": False, "region_mm": [10, 40, 40, 56],
                                   "home_mm": [24, 44, 20], "sweep_climb_mm": 1.0})
    h.node.specimen.surface = slope(-0.09)
    plan = h.node.control._plan(ProbeAt(x_mm=24.0, y_mm=50.0))
    slide = [w for w in plan.waypoints if abs(w.x_mm - 24.0) < 1e-9 and 46.9 < w.y_mm < 53.1]
    assert slide[0].y_mm == pytest.approx(47.0) and slide[-1].y_mm == pytest.approx(53.0)


def test_the_simulated_probe_indents_a_thinning_layer_deeper_than_a_thickening_one() -> None:
    """Why (the cause of the blank dome's false detections): the simulated probe's bore friction holds the indenter
    on the extending side of its play while the layer under it thickens and pushes it to the other side while it
    thins, so the same line reads deeper (softer, by eq. 7) one way than the other. Sweeping only uphill keeps every
    sweep on one side."""
    ph = load_phantom(DOME)
    drv = SimFibreDriver(ph, lambda: 0, errors=ProbeErrors.draw(0, noise_mm=0.0), seed=0)
    y = np.linspace(47.0, 53.0, 61)
    x = np.full_like(y, 24.0)
    kpa = np.full_like(y, 36.0)

    def depth(ys: np.ndarray) -> np.ndarray:
        """d_in (eqs. 1-3) along the line swept through ``ys``, in the order of ``y``."""
        drv._depth = 0.0   # lands from the air (the indenter extending onto the tissue)
        z = np.asarray(ph.thickness(x, ys), dtype=float) + 1.0   # the working offset over the surface
        d_in, _ = indentation_from_heights(*drv.heights(x, ys, z, kpa).T)
        d = np.asarray(d_in, dtype=float)
        return d if ys[0] < ys[-1] else d[::-1]

    climbing, descending = depth(y[::-1]), depth(y)   # up the dome's far edge is -y
    far = y >= 49.0   # past the descending sweep's first 2 mm (stuck in its play)
    assert np.all(descending[far] - climbing[far] > 0.03)   # ~4 % deeper: ~7 % softer by eq. 7
