"""The false-alarm laws of the map detector (models.detector, step 4): for each probe, the Gumbel law of a blank
map's largest significance, fitted by bench/detector_calibration.py on blank specimens; and the fit itself.

A law is (location at the reference area, scale, reference area): a blank map of area A shows a largest significance
~ Gumbel(loc + scale ln(A / reference), scale). models.detector turns it into a threshold for a stated false-alarm
rate per map."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = ["ADAPTIVE_GUMBEL_LOC", "ADAPTIVE_GUMBEL_SCALE", "ADAPTIVE_REFERENCE_AREA_MM2", "BUDGET_GUMBEL_LOC",
           "BUDGET_GUMBEL_SCALE", "CAMERA_GUMBEL_LOC", "CAMERA_GUMBEL_SCALE", "CAMERA_REFERENCE_AREA_MM2",
           "FALSE_ALARM_LAWS", "GUMBEL_LOC", "GUMBEL_SCALE", "PARTIAL_MAP_LAWS", "REFERENCE_AREA_MM2",
           "false_alarm_law", "fit_false_alarm_law"]

FloatArray = npt.NDArray[np.float64]

# fitted by bench/detector_calibration.py on 40 blank scans (runs of 28 Nov 2026, BENCHMARKS.md "Finding all four")
GUMBEL_LOC = 2.447
"""Location (σ) of the Gumbel law of a blank map's largest significance, at :data:`REFERENCE_AREA_MM2`."""
GUMBEL_SCALE = 0.344
"""Scale (σ) of that Gumbel law."""
REFERENCE_AREA_MM2 = 2500.0
"""The valid area of the blank maps the law was fitted on (their raster's cells: 48 mm squares)."""
# the camera probe's: fitted by bench/detector_calibration.py on 40 blank camera scans (its 10 mm sheet and a 12-8 mm
# dome, image-noise seeds 0-19 each; runs of 28 Nov 2026, BENCHMARKS.md "The camera probe's false-alarm law")
CAMERA_GUMBEL_LOC = 2.118
"""Location (σ) of the Gumbel law of a blank camera-probe map's largest significance, at
:data:`CAMERA_REFERENCE_AREA_MM2`."""
CAMERA_GUMBEL_SCALE = 0.321
"""Scale (σ) of that Gumbel law."""
CAMERA_REFERENCE_AREA_MM2 = 2112.0
"""The valid area of the blank camera maps it was fitted on (their 4 mm grid of presses over a 60 mm specimen)."""
# the adaptive planner's maps (air-float): fitted by bench/detector_calibration.py --planner on 40 blank adaptive
# scans (the same sheet and dome, seeds 0-19; runs of 29 Nov 2026, BENCHMARKS.md "The planner's own false-alarm law").
# The planner resolves what its law calls suspect, so the law shapes the maps it is fitted on: the one fitted before
# (2.483, 0.303) let 2 of 40 blank maps over its bar, the refit (2.433, 0.340) in force made the tail heavier, and
# this one, fitted on the maps made with that in force, leaves 0 of 40 over its own bar with itself in force
# (largest 3.58 sigma against 4.78)
ADAPTIVE_GUMBEL_LOC = 2.460
"""Location (σ) of the Gumbel law of a blank adaptive map's largest significance, at
:data:`ADAPTIVE_REFERENCE_AREA_MM2`: the planner's maps as ``launch/scan_adaptive_sim.yaml`` makes them (eq. 7's
thickness measured by the probe at every sample, every sweep on a slope climbing: nodes.scanner.scan_control)."""
ADAPTIVE_GUMBEL_SCALE = 0.399
"""Scale (σ) of that Gumbel law, about a whole map's (0.344). With the thickness read from a measured-geometry file
(its calliper's 0.2 mm errors on a 5 mm grid, interpolated) and sweeps taken both ways on the dome, the same blank
scans gave 2.683 and 0.640: a heavy tail, the dome's thin edge read as an inclusion at 6.7-7.7 σ on two maps of
forty."""
ADAPTIVE_REFERENCE_AREA_MM2 = 2080.0
"""The valid area of the blank adaptive maps it was fitted on."""
BUDGET_GUMBEL_LOC = 3.203
"""Location (σ) of the law of a *budgeted* planner's blank maps (``budget_fraction`` 0.2 of the raster's probes,
models.adaptive_budget), at :data:`ADAPTIVE_REFERENCE_AREA_MM2`: with its budget spent on the coarse pass, the
suspects it cannot afford to resolve stay on a sparse map (6 of the 40 blank maps over the default planner's bar)."""
BUDGET_GUMBEL_SCALE = 0.703
"""Scale (σ) of that law: twice the default planner's."""
PARTIAL_MAP_LAWS: dict[str, tuple[float, float, float]] = {
    "airfloat": (ADAPTIVE_GUMBEL_LOC, ADAPTIVE_GUMBEL_SCALE, ADAPTIVE_REFERENCE_AREA_MM2),
    "airfloat+budget": (BUDGET_GUMBEL_LOC, BUDGET_GUMBEL_SCALE, ADAPTIVE_REFERENCE_AREA_MM2),
}
"""The false-alarm law of an adaptive planner's maps, by probe (models.adaptive_detect.detector_config), measured on its
own blank maps (a partial map's background and noise come from a sparse lattice, the GP's mean fills the cells
between); ``MODEL+budget``: a planner held to a probe budget (measured at 0.2 of the raster's probes)."""
FALSE_ALARM_LAWS: dict[str, tuple[float, float, float]] = {
    "airfloat": (GUMBEL_LOC, GUMBEL_SCALE, REFERENCE_AREA_MM2),
    "multi_indenter": (CAMERA_GUMBEL_LOC, CAMERA_GUMBEL_SCALE, CAMERA_REFERENCE_AREA_MM2),
}
"""The false-alarm law (models.detector.DetectorConfig.gumbel) measured for each probe, by the ``model`` its estimator
states on ``stiffness/sample``: the air-float's sweep maps (2 mm cells, E in kPa) and the camera probe's press grids
(4 mm cells, K_t in N/mm) differ in noise, cell size and correlation, so one's law says nothing of the other's rate."""


def false_alarm_law(model: str, *, partial: bool = False, budget: bool = False) -> tuple[float, float, float] | None:
    """The false-alarm law measured for the probe whose estimator states ``model`` (:data:`FALSE_ALARM_LAWS`; with
    ``partial``, an adaptive planner's maps: :data:`PARTIAL_MAP_LAWS` where one was measured, its ``+budget`` law
    for a planner held to a probe budget with ``budget``, else the whole map's); None for a probe no law was measured
    for (the caller says so and falls back on the default's)."""
    own = None
    if partial:
        own = PARTIAL_MAP_LAWS.get(f"{model}+budget") if budget else None
        own = own if own is not None else PARTIAL_MAP_LAWS.get(model)
    return own if own is not None else FALSE_ALARM_LAWS.get(model)


def fit_false_alarm_law(maxima: npt.ArrayLike, areas_mm2: npt.ArrayLike, reference_area_mm2: float) -> tuple[float, float]:
    """Maximum-likelihood (location at ``reference_area_mm2``, scale) of the Gumbel law of blank maps' largest
    significance, ``maxima[i] ~ Gumbel(loc + scale * ln(areas[i] / reference), scale)`` (module doc, step 4)."""
    top = np.asarray(maxima, dtype=np.float64)
    off = np.log(np.asarray(areas_mm2, dtype=np.float64) / reference_area_mm2)
    if top.size < 2 or not np.all(np.isfinite(top)) or not np.all(np.isfinite(off)):
        raise ValueError(f"fit_false_alarm_law: need two or more finite maxima and positive areas, got {top.size}")

    def nll(p: FloatArray) -> float:
        scale = math.exp(float(p[1]))
        z = (top - float(p[0])) / scale - off
        return float(np.sum(math.log(scale) + z + np.exp(-z)))

    from scipy import optimize

    start = np.array([float(np.mean(top - off)), math.log(max(float(np.std(top)), 1e-3))])
    res = optimize.minimize(nll, start, method="Nelder-Mead", options={"xatol": 1e-7, "fatol": 1e-10})
    return float(res.x[0]), float(math.exp(float(res.x[1])))
