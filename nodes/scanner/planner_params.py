"""The adaptive planner's parameters (nodes.scanner.adaptive_planner.AdaptivePlanner.Params): a module of their own,
as the scanner's (nodes.scanner.scanner_params), so that the node's module holds its behaviour; and
:func:`planner_config`, the one translation of them into the planner's models.adaptive.PlannerConfig, which the node
plans and detects with and a re-detection of its written map (nodes.scanner.planner_map) rebuilds."""

from __future__ import annotations

from typing import Literal

import palpa
from models.adaptive import PlannerConfig
from models.adaptive_budget import with_budget

__all__ = ["PlannerParams", "planner_config"]


class PlannerParams(palpa.Params):
    """The adaptive planner's parameters (launch files set them)."""

    region_mm: list[float] = []
    """x0, y0, x1, y1 the planner probes in (the scanner refuses what is outside its own box); empty: the
    measured footprint (``geometry``) less ``edge_margin_mm``."""
    geometry: str = ""
    """Measured-geometry file (models.geometry), for the footprint when no region is given."""
    edge_margin_mm: float = 6.0
    tip_circle_mm: float = 0.0
    """indent, > 0: the camera probe's soft tips lie on a circle of this radius (models.multi_indenter.ProbeGeometry.
    paper); the planner presses only where every tip lands ``tip_margin_mm`` inside the measured footprint
    (``geometry``), since a press with a tip off the specimen has no valid estimate (models.adaptive_edge)."""
    tip_margin_mm: float = 1.0
    """indent: how far inside the measured footprint's edge every tip must land (its edges' error is 0.2-0.5 mm)."""
    resolution_mm: float = 2.0
    initial: int = 4
    """An initial x initial grid of probes first (unless seed_spacing_mm)."""
    seed_spacing_mm: float = 0.0
    """> 0: the initial grid's points about this far apart instead (a seed that scales with the specimen)."""
    max_length_scale_mm: float = 3.0
    """Upper bound of the GP kernel's length scale (models.adaptive.PlannerConfig.length_scale_mm)."""
    beta: float = 2.0
    implicit_fraction: float = 0.0
    rel_threshold: float = 0.2
    stop_area_mm2: float = 16.0
    epsilon: float = 0.1
    """LSE's accuracy, a fraction of the baseline (models.adaptive.PlannerConfig)."""
    max_probes: int = 60
    stop_rule: Literal["detect", "lse"] = "detect"
    """detect: stop when an inclusion of the sizes of interest is unlikely to hide, every candidate's boundary is
    sampled and every detection's disc measured densely (models.adaptive_detect); lse: LSE's ambiguous area."""
    reach_mm: float = 4.0
    """detect: a measurement within this of an inclusion's centre senses it (smallest radius + sensing reach)."""
    radius_span_mm: float = 4.5
    """detect: the radii of interest span this much above the smallest; the reach grows with them (PlannerConfig)."""
    reach_spread_mm: tuple[float, ...] = (0.0,)
    """detect: how far an inclusion's reach strays from that, as equally likely offsets (PlannerConfig)."""
    interior_gap_mm: float = 3.0
    """detect: every cell of a detected inclusion's disc within this of a measured cell before stopping (0: off)."""
    miss_probability: float = 0.02
    """detect: the chance, below which the planner may stop, that such an inclusion hides unsensed."""
    suspect_false_alarm: float = 0.4
    """detect: regions the map detector reports at this false-alarm rate per map get their boundary sampled."""
    coarse_pass: bool = True
    """detect: first the whole covering lattice (and the sweeps patching its edges), chosen before any is made and
    visited in one short route (models.adaptive_route); false: a seed grid, the rest covered as it goes."""
    fill_mm: float = 4.0
    """detect: the detection map takes the GP mean only this close to a measured cell."""
    false_alarm_per_map: float = 0.003
    """The map detector's false-alarm rate per map (models.detector), as the map aggregator's; the air-float
    planner's maps are partial and are judged by the law of its own blank maps (models.false_alarm.PARTIAL_MAP_LAWS)."""
    split_prominence: float = 1.5
    """detect: split a detection whose measured cells show two maxima this many noise scales above the measured
    level joining them (PlannerConfig; 0: off)."""
    near_miss_false_alarm: float = 0.04
    """detect, > 0: a suspect whose false-alarm probability by the detector's law is at most this gets its disc
    measured at the raster's density (PlannerConfig)."""
    near_miss_gap_mm: float = 1.5
    """detect: a near miss's disc is measured until every cell is within this of a measured one (PlannerConfig)."""
    near_best: float = 1.0
    """detect: the nearest of the covering sweeps revealing at least this fraction of the best one's."""
    cover_column_mm: float = 8.0
    """detect: the covering sweeps on a staggered lattice with columns this far apart (PlannerConfig; 0: off)."""
    cover_period_mm: float = 14.0
    """detect: along a lattice column a sweep every this far, the next column's half a period along."""
    region_gaps: bool = False
    """detect: measure a detection's whole region above the threshold to ``interior_gap_mm``, not only its disc."""
    fair_halo_mm: float = 0.0
    """detect, > 0: blind cells this far past a detection's radius are left out of its background (PlannerConfig)."""
    budget_fraction: float = 0.0
    """detect, > 0: the probes at most this fraction of the raster's probe equivalents over the region, the most
    likely candidates confirmed first when it binds (models.adaptive_budget; 0: ``max_probes`` alone)."""
    spend_budget: bool = False
    """detect, with ``budget_fraction``: after the coarse pass and the likeliest candidates, cover with what is left
    of the budget instead of stopping at ``miss_probability`` (PlannerConfig)."""
    raster_line_mm: float = 3.0
    """The raster's line spacing ``budget_fraction`` is a fraction of (launch/scan_sim.yaml's)."""
    mode: Literal["sweep", "indent"] = "sweep"
    """sweep (air-float probe: a short line) or indent (camera probe: a press)."""
    length_mm: float = 6.0
    radius_mm: float = 3.0
    """Samples within this distance of the point make the scanner's answer (the planner bins them all)."""
    min_count: int = 1
    """Samples a cell needs to count as observed."""
    refit_every: int = 8
    """Re-optimise the GP's hyper-parameters every this many probes (a fit costs seconds, a posterior ms)."""
    retries: int = 2
    call_timeout_s: float = 120.0
    """Seconds of the node's clock a probe may take before the planner gives it up (simulated time on a
    simulated clock)."""
    output_dir: str = "out"
    title: str = ""


def planner_config(params: PlannerParams, region: tuple[float, float, float, float]) -> PlannerConfig:
    """The planner's settings from its parameters and the region it probes in (the node's set-up works the region
    out: ``region_mm``, or the measured footprint, cut for the camera probe's tips), ``max_probes`` lowered as
    ``budget_fraction`` asks (models.adaptive_budget.with_budget). ``model`` is left '': the estimator's samples
    name it. Raises ValueError on settings PlannerConfig refuses."""
    p = params
    cfg = PlannerConfig(region, resolution_mm=p.resolution_mm, initial=p.initial, beta=p.beta,
                        implicit_fraction=p.implicit_fraction, epsilon=p.epsilon, rel_threshold=p.rel_threshold,
                        stop_area_mm2=p.stop_area_mm2, max_probes=p.max_probes, seed_spacing_mm=p.seed_spacing_mm,
                        length_scale_mm=(1.0, p.max_length_scale_mm), stop_rule=p.stop_rule, reach_mm=p.reach_mm,
                        radius_span_mm=p.radius_span_mm, reach_spread_mm=tuple(float(v) for v in p.reach_spread_mm),
                        interior_gap_mm=p.interior_gap_mm, miss_probability=p.miss_probability, fill_mm=p.fill_mm,
                        suspect_false_alarm=p.suspect_false_alarm, false_alarm_per_map=p.false_alarm_per_map,
                        near_miss_false_alarm=p.near_miss_false_alarm, near_miss_gap_mm=p.near_miss_gap_mm,
                        split_prominence=p.split_prominence, near_best=p.near_best,
                        cover_column_mm=p.cover_column_mm, region_gaps=p.region_gaps,
                        cover_period_mm=p.cover_period_mm, fair_halo_mm=p.fair_halo_mm,
                        budget_fraction=p.budget_fraction, raster_line_mm=p.raster_line_mm,
                        spend_budget=p.spend_budget, sweep_mm=p.length_mm if p.mode == "sweep" else 0.0)
    return with_budget(cfg)
