"""Print where a scan wrote its map and what it found: ``python -m nodes.scan_report RUN_DIR [--phantom FILE]``.

With ``--phantom``, each detected inclusion is matched to the nearest true one and the centroid error shown.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scan_report", description=__doc__)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--map-dir", type=Path, help="default: RUN_DIR/map")
    ap.add_argument("--phantom", type=Path, help="compare with the phantom's true inclusions")
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
    truth = []
    if args.phantom:
        from models.phantom import load_phantom

        truth = [tuple(i.center_mm) for i in load_phantom(args.phantom).inclusions]
    print(f"{len(found)} inclusion(s) found:")
    for i, inc in enumerate(found, 1):
        line = (f"  {i}. at ({inc['x_mm']:5.1f}, {inc['y_mm']:5.1f}) mm  radius {inc['radius_mm']:4.1f} mm  "
                f"contrast {inc['contrast']:.2f}")
        if truth:
            err = min(math.dist((inc["x_mm"], inc["y_mm"]), t) for t in truth)
            line += f"  ({err:.2f} mm from the nearest true inclusion)"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
