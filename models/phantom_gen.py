"""Random phantoms from a seed, so a scan method can be judged on many worlds instead of one.

:func:`random_phantom` draws a phantom file's contents (the mapping ``models.phantom.parse_phantom`` reads): a size,
a flat or domed thickness, a background modulus and a few cylindrical inclusions whose radius, stiffness ratio and
depth come from :class:`PhantomRanges`. Inclusions never overlap each other, stay ``margin_mm`` inside the edges,
and always lie below the local surface (depth < local thickness). The same seed gives the same phantom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PhantomRanges", "random_phantom"]


@dataclass(frozen=True)
class PhantomRanges:
    """Inclusive ranges the generator draws from (mm, kPa; ``ratio`` is inclusion / background modulus)."""

    size_mm: tuple[float, float] = (40.0, 70.0)
    thickness_mm: tuple[float, float] = (2.5, 6.0)
    dome_probability: float = 0.5
    """Chance of a domed top (centre ``thickness``, edges ``edge_fraction`` of it) instead of a flat one."""
    edge_fraction: tuple[float, float] = (0.5, 0.8)
    background_kpa: tuple[float, float] = (10.0, 40.0)
    inclusions: tuple[int, int] = (0, 4)
    radius_mm: tuple[float, float] = (2.5, 7.0)
    ratio: tuple[float, float] = (1.5, 6.0)
    depth_mm: tuple[float, float] = (0.5, 2.5)
    margin_mm: float = 4.0
    """Distance kept between an inclusion's edge and the phantom's edge, and between two inclusions."""

    def __post_init__(self) -> None:
        for name in ("size_mm", "thickness_mm", "edge_fraction", "background_kpa", "inclusions", "radius_mm",
                     "ratio", "depth_mm"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or not math.isfinite(hi):
                raise ValueError(f"PhantomRanges.{name}: expected 0 <= low <= high, got ({lo}, {hi})")
        if not 0 <= self.dome_probability <= 1:
            raise ValueError(f"PhantomRanges.dome_probability: expected 0..1, got {self.dome_probability}")


def random_phantom(seed: int, ranges: PhantomRanges | None = None, *, name: str | None = None,
                   attempts: int = 200) -> dict[str, Any]:
    """The contents of a phantom file drawn from ``seed``; fewer inclusions than drawn when they do not fit."""
    r = ranges or PhantomRanges()
    rng = np.random.default_rng(seed)

    def uniform(lo_hi: tuple[float, float]) -> float:
        return float(rng.uniform(lo_hi[0], lo_hi[1]))

    size = (round(uniform(r.size_mm), 1), round(uniform(r.size_mm), 1))
    centre = round(uniform(r.thickness_mm), 2)
    domed = bool(rng.random() < r.dome_probability)
    edge = round(centre * uniform(r.edge_fraction), 2) if domed else centre
    thickness: float | dict[str, float] = {"center": centre, "edge": edge} if domed else centre
    background = round(uniform(r.background_kpa), 1)
    wanted = int(rng.integers(r.inclusions[0], r.inclusions[1] + 1))
    placed: list[tuple[float, float, float]] = []
    inclusions = []
    for _ in range(wanted):
        radius = round(uniform(r.radius_mm), 2)
        lo = radius + r.margin_mm
        if size[0] < 2 * lo or size[1] < 2 * lo:
            continue
        spot = None
        for _ in range(attempts):
            x, y = round(float(rng.uniform(lo, size[0] - lo)), 2), round(float(rng.uniform(lo, size[1] - lo)), 2)
            if all(math.dist((x, y), (px, py)) >= radius + pr + r.margin_mm for px, py, pr in placed):
                spot = (x, y)
                break
        if spot is None:
            continue
        # below the surface everywhere the inclusion is: the thinnest point of a dome is its edge
        depth = round(min(uniform(r.depth_mm), 0.8 * min(centre, edge)), 2)
        ratio = uniform(r.ratio)
        placed.append((spot[0], spot[1], radius))
        inclusions.append({"center_mm": list(spot), "radius_mm": radius, "depth_mm": depth,
                           "youngs_modulus_kpa": round(background * ratio, 1)})
    return {
        "name": name or f"random_{seed}",
        "description": f"random phantom, seed {seed} (models.phantom_gen)",
        "size_mm": list(size),
        "thickness_mm": thickness,
        "youngs_modulus_kpa": background,
        "poisson_ratio": 0.5,
        "inclusions": inclusions,
        "noise": {"displacement_mm": 0.005, "pressure_kpa": 0.01, "pixel": 0.3},
    }

