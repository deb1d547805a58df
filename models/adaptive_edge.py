"""Where a press can be answered: the region a planner of presses may choose its points in (issue 20, camera probe).

The camera probe (models.multi_indenter) solves eq. 5 only with all four indenters in contact: a tip off the
specimen is not displaced and the estimate is invalid ("too few indenters in contact"). Its three soft tips lie on a
circle of 8 mm (ProbeGeometry.paper) at 90 deg, -12 deg and 192 deg from +x: from the press point one reaches 8 mm
towards +y, two 7.8 mm towards +x and -x, and none more than 1.7 mm towards -y. A press nearer the footprint's edge
than that on the +x, -x or +y side has a tip off the specimen and no valid estimate, wherever the press is made and
however often it is asked. The usual region, the footprint less a 6-7 mm margin on every side, has three such edges:
the raster's 4 mm grid of presses (launch/scan_camera_sim.yaml) gets no valid estimate at any of its presses on
them either (37 of 169 on ``flat_26k_tumours``: every press at x0, x1 and y1, 2 at y0's corners); its map simply has
no value there. A planner that chooses its points in that region asks for them, is refused, and LSE's rule, which
counts the never-measured edge cells as ambiguous, asks for the next.

:func:`press_region` is the given region cut to the press points whose every tip lies at least a margin inside the
measured footprint: the planner's belief, its candidate points and its stop rule are then over tissue it can measure.
:func:`probe_tips` gives the tips of the camera probe's geometry. Pure: no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence

from models.multi_indenter import ProbeGeometry

__all__ = ["Region", "press_region", "probe_tips"]

Region = tuple[float, float, float, float]
"""x0, y0, x1, y1 in mm."""


def probe_tips(circle_radius_mm: float) -> list[tuple[float, float]]:
    """The indenter tips' offsets (x, y) in mm from the press point of the camera probe whose soft tips lie on a
    circle of ``circle_radius_mm`` (:meth:`models.multi_indenter.ProbeGeometry.paper`, its hard tip at the centre)."""
    g = ProbeGeometry.paper(radius_mm=circle_radius_mm)
    return list(zip(g.x_mm, g.y_mm, strict=True))


def press_region(region: Region, footprint: Region, tips: Sequence[tuple[float, float]], margin_mm: float) -> Region:
    """``region`` less the press points where a tip (offsets ``tips`` from the press point) would lie nearer than
    ``margin_mm`` to the edge of ``footprint`` or past it: on each side the nearer of the two bounds. ``tips`` empty:
    ``region`` as it is. ValueError when nothing is left (a specimen too small for the probe's tips)."""
    if not tips:
        return region
    if not (margin_mm >= 0):
        raise ValueError(f"press_region: margin_mm must be >= 0, got {margin_mm}")
    fx0, fy0, fx1, fy1 = footprint
    txs = [t[0] for t in tips]
    tys = [t[1] for t in tips]
    reach = (fx0 + margin_mm - min(txs), fy0 + margin_mm - min(tys),
             fx1 - margin_mm - max(txs), fy1 - margin_mm - max(tys))
    x0, y0, x1, y1 = max(region[0], reach[0]), max(region[1], reach[1]), min(region[2], reach[2]), \
        min(region[3], reach[3])
    if not (x0 <= x1 and y0 <= y1):
        raise ValueError(f"no press point in the region x {region[0]:g}..{region[2]:g}, y {region[1]:g}..{region[3]:g} "
                         f"mm keeps every tip {margin_mm:g} mm inside the footprint x {fx0:g}..{fx1:g}, "
                         f"y {fy0:g}..{fy1:g} mm (the tips reach x {min(txs):+.1f}..{max(txs):+.1f}, "
                         f"y {min(tys):+.1f}..{max(tys):+.1f} mm from the press point)")
    return x0, y0, x1, y1
