"""Flat samples against the air-float paper's Fig. 11: E from a pressure ramp's eq. 7 fit, before and after calibration.

The paper tested each silicone sample (26.4 and 10.8 kPa, 20 mm) at four locations, three ramps each, to 3 mm,
and reports eq. 7 averages of 25 +- 5 kPa and 10 +- 4 kPa. Here the same protocol runs through the real nodes
(regulator, fibre reader, estimator with ``ramp_fits``) in-process on a simulated clock, over the FE-grounded world
with the simulated probe's drawn errors (``--device-seed``); each ramp has its own regulator seed. Before: eq. 4's
paper line and no depth offset. After: the file written by ``tools.calibrate_airfloat`` for the same probe.

    .venv/bin/python bench/airfloat_flat.py [--device-seed 0] [--calibration FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from messages import PressureCommand, StiffnessFit  # noqa: E402
from nodes.probe.fibre_reader import FibreReader  # noqa: E402
from nodes.probe.pressure_controller import PressureController  # noqa: E402
from nodes.probe.stiffness_estimator import AirfloatStiffnessEstimator  # noqa: E402
from nodes.scanner.static_pose import StaticPose  # noqa: E402
from palpa.testing import GraphHarness  # noqa: E402
from tools.calibrate_airfloat import DEFAULT_REFERENCES, Reference, calibrate  # noqa: E402

SAMPLES = [("flat_26k", 26.4, 42.5), ("flat_10k", 10.8, 35.6)]  # name, truth, ramp target (kPa): ~3 mm deep
LOCATIONS = [(20.0, 20.0), (40.0, 20.0), (20.0, 40.0), (40.0, 40.0)]


def ramp_fit(sample: str, xy: tuple[float, float], target: float, device_seed: int, seed: int,
             calibration: str) -> StiffnessFit | None:
    geo = str(REPO / "phantoms" / "measured" / f"{sample}.yaml")
    with GraphHarness() as g:
        g.add(StaticPose, {"x_mm": xy[0], "y_mm": xy[1], "z_mm": 21.0})
        g.add(PressureController, {"startup": "hold", "setpoint_kpa": 30.0, "seed": seed,
                                   "calibration": calibration})
        g.add(FibreReader, {"phantom": str(REPO / "phantoms" / f"{sample}.yaml"), "device_seed": device_seed,
                            "seed": seed})
        g.add(AirfloatStiffnessEstimator, {"geometry": geo, "ramp_fits": True, "max_depth_mm": 3.3,
                                           "calibration": calibration})
        g.advance(1.0)
        g.publish("pressure/command", PressureCommand(mode="ramp", setpoint_kpa=target, rate_kpa_s=2.0))
        g.advance((target - 30.0) / 2.0 + 1.0)
        fits = g.published("stiffness/fit", StiffnessFit)
    return fits[-1] if fits else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device-seed", type=int, default=0)
    ap.add_argument("--calibration", type=Path, help="default: calibrate now (tools.calibrate_airfloat)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    cal_path = args.calibration
    if cal_path is None:
        cal_path = Path(tempfile.mkdtemp()) / "calibration.yaml"
        from models.calibration_airfloat import save_calibration

        cal = calibrate(args.device_seed, [Reference.parse(t) for t in DEFAULT_REFERENCES])
        save_calibration(cal_path, cal)
        print(f"calibration (device {args.device_seed}): gain {cal.force.gain:.3f} offset {cal.force.offset:+.3f} N,"
              f" depth offset {cal.depth_offset_mm:+.3f} mm, line RMSE {cal.force_line_rmse_n:.4f} N")
    out: dict[str, dict[str, list[float]]] = {}
    for stage, calib in (("before", ""), ("after", str(cal_path))):
        for name, truth, target in SAMPLES:
            es = []
            for i, xy in enumerate(LOCATIONS):
                for rep in range(3):
                    fit = ramp_fit(name, xy, target, args.device_seed, 100 * i + rep, calib)
                    if fit is not None:
                        es.append(fit.e_corrected_kpa)
            out.setdefault(name, {})[stage] = es
            e = np.array(es)
            print(f"{stage:6s} {name}: truth {truth} kPa, eq. 7 ramp fits {e.mean():.1f} +- {e.std(ddof=1):.1f} kPa "
                  f"(n {e.size}, range {e.min():.1f}-{e.max():.1f}, mean error {100 * (e.mean() / truth - 1):+.1f} %)")
    print(f"wall {time.perf_counter() - t0:.0f} s")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
