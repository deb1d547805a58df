"""Cost of the world's queries against the stress bulb it replaces (in-process, CPU time).

    nice python -m bench.world_speed

Prints CPU microseconds per point for TissueWorld.force_n / depth_mm on the Fig. 12 phantom (four
inclusions), batched (500 random points a call) and one point a call, and each as a ratio to
``Phantom.effective_modulus`` on the same points (the old world's per-sample model).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from models.phantom import load_phantom
from models.world import TissueWorld


def _per_call(fn: Callable[[], object], repeat: int) -> float:
    fn()
    t0 = time.process_time()
    for _ in range(repeat):
        fn()
    return (time.process_time() - t0) / repeat


def main() -> None:
    """Time the queries and print one line each."""
    phantom = load_phantom(Path(__file__).parents[1] / "phantoms" / "airfloat_tumours.yaml")
    world = TissueWorld(phantom)
    rng = np.random.default_rng(1)
    n = 500
    x, y = rng.uniform(1, 59, n), rng.uniform(1, 59, n)
    d = rng.uniform(0.05, 1.4, n)
    f = np.asarray(world.force_n(x, y, d))
    rows = [
        ("force_n, 500 a call", lambda: world.force_n(x, y, d), n, 20),
        ("depth_mm, 500 a call", lambda: world.depth_mm(x, y, f), n, 5),
        ("stress bulb, 500 a call", lambda: phantom.effective_modulus(x, y, 4.0, d), n, 20),
        ("force_n, 1 a call", lambda: world.force_n(15.0, 18.0, 0.8), 1, 300),
        ("depth_mm, 1 a call", lambda: world.depth_mm(15.0, 18.0, 0.1), 1, 100),
        ("stress bulb, 1 a call", lambda: phantom.effective_modulus(15.0, 18.0, 4.0, 0.8), 1, 300),
    ]
    timed = {name: _per_call(fn, repeat) / points * 1e6 for name, fn, points, repeat in rows}
    for name, us in timed.items():
        batching = name.split(", ")[1]
        ratio = us / timed[f"stress bulb, {batching}"]
        print(f"{name:26s} {us:9.1f} us/point   {ratio:5.1f} x the stress bulb")


if __name__ == "__main__":
    main()
