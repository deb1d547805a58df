"""What the emulated controller's tool feels and reads: the specimen's push-back on the probe tip, and the TCP force
sensor that reads it.

The push-back comes from the simulated world only: models.world's FE-grounded tissue within its tables, the rigid
table under the tissue past them (BACKING_N_PER_MM), a reference spring sample's own spring, or a rigid surface for
anything without tissue. The sensor reads that force off by a bias (drawn from a seed, until zeroed) and white noise
(a fresh draw every controller cycle). Split from emulators.ur.controller, which moves the arm, keeps the true
contact force and trips the force limit on it.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from typing import Any, Protocol

__all__ = ["BACKING_N_PER_MM", "ForceSensor", "SpecimenContact", "SurfaceLike"]

# The rigid table under a specimen, felt once the tissue has bottomed out (pressed past the world's tables): steep,
# so a touch-off or a press that goes too deep trips the force limit within a fraction of a millimetre.
BACKING_N_PER_MM = 50.0


class SurfaceLike(Protocol):
    """What the contact model needs from a phantom (models.phantom.Phantom): the height (mm)
    of the tissue surface above the table at (x, y) in the phantom frame (mm). A Phantom's tissue gives the
    contact force through models.world's FE-grounded world; anything else is a rigid surface."""

    def surface_z(self, x_mm: Any, y_mm: Any, /) -> Any: ...


class SpecimenContact:
    """The specimen under the probe tip: how hard it pushes back on a tip pressed into it."""

    def __init__(self, phantom: SurfaceLike) -> None:
        self.phantom = phantom
        self._world: Any = None
        self._world_made = False

    def press_force(self, pose: Sequence[float], origin_mm: Sequence[float], tip_radius_mm: float) -> float:
        """Force (N) on the tip at ``pose`` (base frame, mm; the phantom frame's origin at ``origin_mm``): 0 above
        the surface or outside the phantom."""
        p, o = pose, origin_mm
        try:
            surface = float(self.phantom.surface_z(p[0] - o[0], p[1] - o[1]))
        except (ValueError, IndexError):
            surface = math.nan  # outside the phantom
        depth = surface - (p[2] - o[2]) if math.isfinite(surface) else 0.0
        fz = 0.0
        if depth > 0:
            fz = self.force_n(p[0] - o[0], p[1] - o[1], depth, tip_radius_mm)
        return fz

    def _tissue_world(self) -> Any:
        """models.world.TissueWorld over the phantom (None for a surface without tissue, or a spring sample)."""
        if not self._world_made:
            self._world_made = True
            try:
                from models.world import TissueWorld

                self._world = TissueWorld(self.phantom)  # type: ignore[arg-type]
            except (ImportError, ValueError, TypeError, AttributeError):
                self._world = None
        return self._world

    def force_n(self, x: float, y: float, depth: float, r: float) -> float:
        """Force (N) on the tip pressed depth mm into the specimen at (x, y), from the simulated world only.

        The FE-grounded tissue world (models.world) within its tables; past them (deeper than min(r, 0.75 t), or a
        layer thinner than the tables) the tissue has bottomed out on the rigid table under it, which pushes back
        at BACKING_N_PER_MM. A spring sample is its spring. Nothing here is an estimator's formula.
        """
        phantom = self.phantom
        if getattr(phantom, "is_spring_sample", False):  # a reference spring sample: its spring, linear
            return float(phantom.spring_constant(x, y, r, depth)) * depth  # type: ignore[attr-defined]
        world = self._tissue_world()
        if world is None:  # a surface without tissue (a test's plane): rigid
            return BACKING_N_PER_MM * depth
        # past the tables only (any other error is a bug and is raised); imported lazily, as in _tissue_world
        from models.world import WorldRangeError

        try:
            f = float(world.force_n(x, y, depth, indenter_radius_mm=r))
            return f if math.isfinite(f) else 0.0  # nan: off the footprint
        except WorldRangeError:
            pass
        try:
            deepest = float(world.deepest_mm(x, y, indenter_radius_mm=r))
            base = float(world.force_n(x, y, deepest, indenter_radius_mm=r))
        except WorldRangeError:  # a layer thinner than the tables: the table is right under the tip
            deepest, base = 0.0, 0.0
        return base + BACKING_N_PER_MM * max(0.0, depth - deepest)


class ForceSensor:
    """The TCP force sensor: a force reads off by a bias of up to ``bias_n`` per force axis (drawn from ``seed``)
    and this cycle's noise, until :meth:`zero` takes the reading then as its zero."""

    def __init__(self, bias_n: float, seed: int) -> None:
        self._rng = random.Random(seed)
        self._bias = [self._rng.uniform(-bias_n, bias_n) for _ in range(3)] + [0.0] * 3
        self._noise = [0.0] * 6
        self._offset = [0.0] * 6

    def draw_noise(self, sigma_n: float) -> None:
        """A new cycle's noise on the force axes: sigma ``sigma_n`` (N), none at 0."""
        self._noise = [self._rng.gauss(0.0, sigma_n) if sigma_n > 0 else 0.0 for _ in range(3)] + [0.0] * 3

    def raw(self, force: Sequence[float]) -> tuple[float, ...]:
        """The reading of ``force`` before zeroing: the force, its bias and this cycle's noise."""
        return tuple(f + b + n for f, b, n in zip(force, self._bias, self._noise, strict=True))

    def zero(self, force: Sequence[float]) -> None:
        """URScript's zero_ftsensor(): the reading of ``force`` now (its noise included) becomes the zero."""
        self._offset = list(self.raw(force))

    def sensed(self, force: Sequence[float]) -> tuple[float, ...]:
        """What the sensor reads of ``force``: its raw reading less the zero."""
        return tuple(r - o for r, o in zip(self.raw(force), self._offset, strict=True))
