"""Print where a scan wrote its map and what it found: ``python -m tools.scan_report RUN_DIR [--phantom FILE]``.

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
    args = ap.parse_args(argv)
    out = args.map_dir or args.run_dir / "map"
    inc_file = out / "inclusions.json"
    if not inc_file.exists():
        print(f"scan_report: no {inc_file}: did the scan finish? (logs in {args.run_dir})", file=sys.stderr)
        return 1
    found = json.loads(inc_file.read_text())
    print(f"map:        {out / 'map.png'}")
    print(f"grid:       {out / 'map.npz'}")
    print(f"inclusions: {inc_file}")
    rec = args.run_dir / "recording.mcap"
    if rec.exists():
        print(f"recording:  {rec}  (palpa bag info {rec})")
    print(f"{len(found)} inclusion(s) found:")
    for i, inc in enumerate(found, 1):
        print(f"  {i}. at ({inc['x_mm']:5.1f}, {inc['y_mm']:5.1f}) mm  radius {inc['radius_mm']:4.1f} mm  "
              f"contrast {inc['contrast']:.2f}")
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
