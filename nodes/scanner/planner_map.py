"""An adaptive planner's written map detected again by the planner's own rule, not the raster's.

The planner detects on a partial map (models.adaptive_detect.detect_candidates: the measured cells and the GP mean
near them), its background and noise from the stiffness-blind sweeps' cells, by the false-alarm law of its own blank
maps (models.false_alarm.PARTIAL_MAP_LAWS) and with its own settings (fill, split, halo, budget). The whole-map
detector that re-detects a raster's map (nodes.mapping.map_output.redetect) is another rule on such a map: on one
bench set it missed 14 inclusions where the planner's own detection had missed 6. So the planner keeps in its
``map.npz`` what its rule needs: its parameters and region (``planner``: :func:`planner_settings`, rebuilt into its
settings by the node's own nodes.scanner.planner_params.planner_config), the cells it detected from (the ``measured``
and ``fair`` layers) and the probe's ``model``; :func:`redetect_map` runs the planner's rule on a planner's map and
the whole-map detector on any other. A planner's map without them (written before they were kept) is refused
(:class:`PlannerMapError`), never detected by the whole-map rule in their place.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import msgspec
import numpy as np

from models.adaptive import Belief, PlannerConfig
from models.adaptive_detect import detect_candidates, detector_config
from models.detector import Detection, detect
from nodes.mapping.map_output import map_model, read_map, redetect
from nodes.scanner.planner_params import PlannerParams, planner_config
from palpa.errors import ParamError
from palpa.node.params import convert_params

__all__ = ["PlannerMapError", "is_planner_map", "planner_settings", "redetect_map", "redetect_planner"]

SETTINGS = "planner"
"""The 0-d JSON string in ``map.npz`` holding the planner's parameters and region (:func:`planner_settings`)."""
LAYERS = ("measured", "fair")
"""The grids in ``map.npz`` the planner's detection read (nodes.scanner.adaptive_planner writes them)."""


class PlannerMapError(ValueError):
    """An adaptive planner's map that its own rule cannot be run on again: the message names the file and what it
    lacks."""


def planner_settings(params: PlannerParams, region: tuple[float, float, float, float]) -> str:
    """The planner's parameters (every one, as it ran) and the region it worked out at set-up (from a footprint
    and the probe's tips, which a reader of the map does not have), as the JSON kept in its ``map.npz``."""
    return json.dumps({"params": msgspec.to_builtins(params), "region_mm": [float(v) for v in region]})


def is_planner_map(npz: Path) -> bool:
    """Whether ``npz`` is an adaptive planner's map: it keeps the planner's settings, its layers or its unsensed
    cells, or the planner's ``planner.json`` lies beside it (a planner's map written before any of them was kept)."""
    if (npz.parent / "planner.json").exists():
        return True
    with np.load(npz) as d:
        return any(name in d.files for name in (SETTINGS, *LAYERS, "unsensed"))


def _config(npz: Path, text: str, model: str) -> PlannerConfig:
    """The settings the planner detected with, from its kept parameters and region and the probe's ``model``."""
    try:
        kept = json.loads(text)
        params = convert_params(PlannerParams, kept["params"], where=f"{npz}: {SETTINGS}")
        x0, y0, x1, y1 = (float(v) for v in kept["region_mm"])
        cfg = planner_config(params, (x0, y0, x1, y1))
    except (ValueError, KeyError, TypeError, ParamError) as exc:
        raise PlannerMapError(f"{npz}: the adaptive planner's settings ({SETTINGS!r}) cannot be read: {exc}") from None
    return replace(cfg, model=model)   # the planner's, as its samples named it (map_output writes it when named)


def redetect_planner(npz: Path) -> Detection:
    """The adaptive planner's final detection run again on its written ``map.npz``, by its own rule (module doc):
    with the detect stop rule models.adaptive_detect.detect_candidates on the written map (the measured cells, the
    GP mean within ``fill_mm`` of them) with the ``measured`` and ``fair`` layers; with lse the map detector on the
    GP mean, by the planner's partial-map law. Raises :class:`PlannerMapError` when the map lacks the planner's
    settings or a layer its rule reads, OSError, KeyError or ValueError on a file that is not a map."""
    with np.load(npz) as d:
        text = str(d[SETTINGS]) if SETTINGS in d.files else ""
        model = str(d["model"]) if "model" in d.files else ""
        layers = {name: np.asarray(d[name], dtype=np.float64) for name in LAYERS if name in d.files}
    absent = [name for name in LAYERS if name not in layers]
    if not text:
        what = " and ".join([f"its settings ({SETTINGS!r})", *(f"the {name!r} layer" for name in absent)])
        raise PlannerMapError(f"{npz}: an adaptive planner's map without {what}, which its detection rule needs "
                              "(a map written before planner maps kept them): it is not detected again by the "
                              "whole-map detector, a different rule; use its own inclusions.json, or scan again")
    cfg = _config(npz, text, model)
    snap = read_map(npz)
    if cfg.stop_rule != "detect":   # lse: the map is the GP mean, detected as a whole by the partial-map law
        return detect(replace(snap, resolution_mm=cfg.resolution_mm), detector_config(cfg))
    if absent:
        raise PlannerMapError(f"{npz}: an adaptive planner's map without the "
                              + " and ".join(f"{name!r}" for name in absent)
                              + " layer(s), which its detection rule reads (the cells it measured, and of those the "
                              "stiffness-blind sweeps' its background comes from): it is not detected again by the "
                              "whole-map detector, a different rule")
    for name, grid in layers.items():
        if grid.shape != snap.stiffness.shape:
            raise PlannerMapError(f"{npz}: layer {name!r}: shape {grid.shape} is not the map's "
                                  f"{snap.stiffness.shape}")
    # the written map is the planner's detection map: measured where measured, the GP mean near them, NaN farther;
    # taken as the mean, it makes that same map again (the belief's level and baseline are not read)
    belief = Belief(snap.x_mm, snap.y_mm, snap.stiffness, snap.spread, math.nan, math.nan)
    _, det = detect_candidates(belief, layers["measured"], snap.count, cfg, layers["fair"])
    return det


def redetect_map(npz: Path) -> tuple[Detection, str]:
    """A written ``map.npz``'s detection run again by the rule that made it, and that rule named for a report: an
    adaptive planner's map (:func:`is_planner_map`) by the planner's (:func:`redetect_planner`), any other by the
    whole-map detector with its probe's false-alarm law (nodes.mapping.map_output.redetect). Raises
    :class:`PlannerMapError` on a planner's map that lacks what its rule needs, OSError, KeyError or ValueError on a
    file that is not a map."""
    model = map_model(npz) or "unknown"
    if is_planner_map(npz):
        return redetect_planner(npz), f"the adaptive planner's own rule ({model} probe's partial-map false-alarm law)"
    return redetect(npz), f"the whole-map detector ({model} probe's false-alarm law)"
