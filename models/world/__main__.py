"""The researcher's query of the world: ``python -m models.world force PHANTOM.yaml --at X,Y --depth D``.

Prints one JSON line: ``force_n`` and its context (local thickness, materials, the homogeneous
force, the contrast and each contributing inclusion's excess). ``--force F`` instead of ``--depth``
asks the inverse (the depth that carries F newtons). Expected failures print one line and exit 1.
"""

from __future__ import annotations

import argparse
import json
import sys

from models.airfloat import DEFAULT_INDENTER_RADIUS_MM
from models.phantom import PhantomError, load_phantom
from models.world.world import TissueWorld, WorldRangeError


def _point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in mm (e.g. 15,18), got {text!r}") from None
    return x, y


def main(argv: list[str] | None = None) -> int:
    """Parse the command line, query the world, print one JSON line."""
    p = argparse.ArgumentParser(prog="python -m models.world", description=__doc__)
    sub = p.add_subparsers(dest="verb", required=True)
    q = sub.add_parser("force", help="force (N) on the spherical indenter at a point and depth")
    q.add_argument("phantom", help="phantom YAML file")
    q.add_argument("--at", type=_point, required=True, metavar="X,Y", help="point (mm)")
    how = q.add_mutually_exclusive_group(required=True)
    how.add_argument("--depth", type=float, help="indentation below the local surface (mm)")
    how.add_argument(
        "--force", type=float, help="inverse query: the depth (mm) carrying this force (N)"
    )
    q.add_argument(
        "--radius", type=float, default=DEFAULT_INDENTER_RADIUS_MM,
        help="sphere radius (mm), default the air-float indenter's %(default)s",
    )  # fmt: skip
    args = p.parse_args(argv)
    x, y = args.at
    try:
        world = TissueWorld(load_phantom(args.phantom))
        depth = args.depth
        if depth is None:
            depth = float(world.depth_mm(x, y, args.force, indenter_radius_mm=args.radius))
        info = world.explain(x, y, depth, indenter_radius_mm=args.radius)
    except (PhantomError, WorldRangeError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
