"""Print where a scan wrote its map and what it found: ``python -m tools.scan_report RUN_DIR [--phantom FILE]``.

Each inclusion is listed with the detector's significance (SNR) and per-map false-alarm probability when the map
states them. ``--redetect`` runs the detection again on ``map.npz`` instead of reading ``inclusions.json``: what
today's detector finds on a map written earlier, by the rule that made the map (nodes.scanner.planner_map.
redetect_map): a raster's by the map detector (models.detector.detect, the map aggregator's own, with the false-alarm
law of the probe that made the map), an adaptive planner's by the planner's own rule from the settings and layers
its map keeps; a planner's map that lacks them is refused (exit 1), not detected by the raster's rule.

With ``--phantom`` (simulation: the truth, read here after the run and never by the graph) the scan is scored by
``models.scoring.score_scan``: each true inclusion found or missed with its centroid and radius errors, false
positives, and the sensitivity/specificity of the map's inclusion cells against the phantom's inclusion mask.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scan_report", description=__doc__)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--map-dir", type=Path, help="default: RUN_DIR/map")
    ap.add_argument("--phantom", type=Path, help="score the scan against this phantom's true inclusions")
    ap.add_argument("--redetect", action="store_true", help="detect on map.npz again, by the rule that made it (a raster's "
                    "map: models.detector; an adaptive planner's: its own)")
    args = ap.parse_args(argv)
    out = args.map_dir or args.run_dir / "map"
    inc_file = out / "inclusions.json"
    if not inc_file.exists():
        print(f"scan_report: no {inc_file}: did the scan finish? (logs in {args.run_dir})", file=sys.stderr)
        return 1
    found = json.loads(inc_file.read_text())
    if args.redetect:
        from models.stiffness_map import to_inclusions_json
        from nodes.scanner.planner_map import PlannerMapError, redetect_map

        try:
            det, rule = redetect_map(out / "map.npz")
        except PlannerMapError as exc:   # it names the map and what it lacks
            print(f"scan_report: cannot detect again: {exc}", file=sys.stderr)
            return 1
        except (OSError, KeyError, ValueError) as exc:
            print(f"scan_report: cannot detect on {out / 'map.npz'}: {exc}", file=sys.stderr)
            return 1
        found = to_inclusions_json(det.inclusions)
        print(f"redetected on map.npz by {rule}: threshold {det.threshold_snr:.2f} σ, noise "
              f"{100 * det.noise_rel:.1f} % a cell")
    print(f"map:        {out / 'map.png'}")
    print(f"grid:       {out / 'map.npz'}")
    print(f"inclusions: {inc_file}")
    rec = args.run_dir / "recording.mcap"
    if rec.exists():
        print(f"recording:  {rec}  (palpa bag info {rec})")
    print(f"{len(found)} inclusion(s) found:")
    for i, inc in enumerate(found, 1):
        sig = f"  SNR {inc['snr']:.1f}, false alarm {inc['false_alarm']:.1g} a map" if "snr" in inc else ""
        print(f"  {i}. at ({inc['x_mm']:5.1f}, {inc['y_mm']:5.1f}) mm  radius {inc['radius_mm']:4.1f} mm  "
              f"contrast {inc['contrast']:.2f}{sig}")
    if args.phantom:
        from models.phantom import PhantomError, load_phantom
        from models.scoring import score_scan

        try:
            phantom = load_phantom(args.phantom)
            with np.load(out / "map.npz") as grid:
                score = score_scan(phantom, found, grid)
        except (PhantomError, ValueError, OSError) as exc:
            print(f"scan_report: cannot score against {args.phantom}: {exc}", file=sys.stderr)
            return 1
        print(f"against the truth ({args.phantom}): {score.found} of {len(score.inclusions)} found, "
              f"{len(score.false_positives)} false positive(s)")
        for line in score.summary():
            print(f"  {line}")
    from nodes.mapping.map_output import map_incomplete

    why = map_incomplete(out / "map.npz") if (out / "map.npz").exists() else ""
    if why:  # what is above holds part of the scan: a report of it is not a result
        print(f"scan_report: the map is INCOMPLETE: {why}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
