"""A probe budget that scales with the region, and what to confirm first when it cannot pay for every open point.

Issue 41 judges the planner against the raster on the same region: its probes over the raster's *probe
equivalents*, the raster's swept length in contact (a line every ``raster_line_mm`` across the region, along y) over
one sweep's length. The planner can work that number out from its own region before its first probe, so a budget
stated as a fraction of it (``PlannerConfig.budget_fraction``: :func:`with_budget`) is one the planner can keep
whatever the specimen's size, where a fixed ``max_probes`` is a fifth of the raster on one specimen and a third on
another. Nothing of the raster's run is used: only the region and the raster's line spacing.

A budget that binds leaves open points unvisited. Which ones should go first is the detector's own question: the
candidates the map's false-alarm law calls least likely to be noise (their false-alarm probability,
models.detector.false_alarm_probability, smallest first: a detection before a near miss before a loose suspect)
get their points visited; the rest wait (:func:`most_likely`). Our own code.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

from models.adaptive import PlannerConfig

__all__ = ["most_likely", "raster_equivalents", "with_budget"]

Point = tuple[float, float]


def raster_equivalents(region_mm: tuple[float, float, float, float], sweep_mm: float, line_mm: float) -> float:
    """The raster's swept length over ``region_mm`` in sweeps of ``sweep_mm``: lines every ``line_mm`` along x
    (the first on the region's edge: ``floor(width / line_mm) + 1`` of them), each the region's height long. The
    same count bench/adaptive.py divides the planner's probes by."""
    if not (sweep_mm > 0 and line_mm > 0):
        raise ValueError(f"raster_equivalents: sweep_mm and line_mm must be > 0, got {sweep_mm}, {line_mm}")
    x0, y0, x1, y1 = region_mm
    lines = math.floor((x1 - x0) / line_mm + 1e-9) + 1
    return lines * (y1 - y0) / sweep_mm


def with_budget(cfg: PlannerConfig) -> PlannerConfig:
    """``cfg`` with ``max_probes`` lowered to ``budget_fraction`` of the raster's probe equivalents over its region
    (:func:`raster_equivalents`, rounded down, at least one probe); unchanged when ``budget_fraction`` is 0 or the
    planner presses (no sweep length to compare)."""
    if cfg.budget_fraction <= 0 or cfg.sweep_mm <= 0:
        return cfg
    cap = math.floor(cfg.budget_fraction * raster_equivalents(cfg.region_mm, cfg.sweep_mm, cfg.raster_line_mm) + 1e-9)
    return replace(cfg, max_probes=max(1, min(cfg.max_probes, cap)))


def most_likely(priority: Mapping[Point, float], left: int) -> list[Point]:
    """The open points worth the ``left`` probes still in the budget: all of them when they fit; else those of the
    most likely candidates (``priority``: each point's false-alarm probability, smallest first), whole levels at a
    time, until at least ``left`` are taken (so the route may still pick among them). In ``priority``'s order within
    a level; deterministic."""
    if left >= len(priority):
        return list(priority)
    levels = sorted(set(priority.values()))
    out: list[Point] = []
    for p in levels:
        out += [q for q, v in priority.items() if v == p]
        if len(out) >= left:
            break
    return out
