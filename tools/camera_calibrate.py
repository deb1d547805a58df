"""Calibrate a camera probe: press a rigid flat and reference springs, write the calibration file.

    python -m tools.camera_calibrate -o probe7.yaml --device-seed 7            # in simulation
    palpa launch launch/camera_sim.yaml calibration_file:=probe7.yaml ...      # then use it

The procedure is the rig's (docs/camera.md, "Calibration"): the linear stage presses the probe
flat and slowly (the rigid flat at 0.5 mm/s, springs at 1.5 mm/s) into each reference and back out, four
times, while the camera tracker runs at its
nominal scale; what is used is only what the rig observes: the stage's pose and speed on
``robot/pose``, each marker's offset on ``camera/indenters`` (displacement at the nominal scale
times that scale = pixels from the zero reference), and the label K of each reference.
``models.camera_calibration`` fits the pixel -> mm maps on the rigid flat and the springs on the
references. In simulation the references are phantom files (``phantoms/ref_*.yaml``; the labelled
springs are off their labels by a measurement error, as real ones) and the probe is the one the sim
camera draws from ``--device-seed``: calibrate and measure with the same seed. On the rig, record
the same two topics during the same presses and give them to :func:`calibrate`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from messages import IndenterDisplacements, RobotPose
from models.camera_calibration import CalibrationError, ProbeCalibration, fit_scale, fit_springs
from models.multi_indenter import PX_PER_MM

__all__ = ["REFERENCES", "Press", "calibrate", "main", "press_reference"]

HERE = Path(__file__).resolve().parent.parent / "phantoms"
#: (phantom file, label K in N/mm (inf: the rigid flat), press depth mm, speed mm/s) of the simulated calibration.
#: The rigid flat goes to 9 mm (inside the 10 mm stroke) slowly, so that the tracker's filter has settled a few
#: pixels past the knee and the pixel maps hold down to 8 px (the hard marker travels only 1-4 mm on the springs);
#: 0.10 N/mm suits the soft springs (a slope near 2/3) and, pressed 11 mm, gives the hard one 3 mm of travel;
#: 0.25 N/mm suits the hard spring (slope 1/2).
REFERENCES: tuple[tuple[str, float, float, float], ...] = (
    (str(HERE / "ref_rigid.yaml"), math.inf, 9.0, 0.5),
    (str(HERE / "ref_spring_010.yaml"), 0.10, 11.0, 1.5),
    (str(HERE / "ref_spring_025.yaml"), 0.25, 9.0, 1.5),
)

#: Time (s) after a change of the stage's speed before frames are used (the filter's settling, ~7 frames, and more).
SETTLE_S = 0.6

Press = tuple[list[RobotPose], list[IndenterDisplacements]]


def _series(press: Press) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame with every marker seen: stage travel (mm), direction of motion, marker offsets (px)."""
    poses, frames = press
    stamps = np.array([p.stamp_ns for p in poses], dtype=np.float64)
    z = np.array([p.z_mm for p in poses])
    speed = np.array([p.speed_mm_s for p in poses])
    frames = [m for m in frames if all(m.valid)]
    t_frame = np.array([m.stamp_ns for m in frames], dtype=np.float64)
    travel = z.max() - np.interp(t_frame, stamps, z)
    idx = np.clip(np.searchsorted(stamps, t_frame), 0, len(stamps) - 1)
    direction = -np.sign(speed[idx])
    # The tracker's Kalman filter lags a moving marker by a constant once it has settled to the stage's speed
    # (the fits take that with a term in the direction of motion); frames soon after a change of speed are not
    # settled, and are left out like the holds.
    changes = stamps[1:][np.diff(speed) != 0]
    last = np.searchsorted(changes, t_frame, side="right") - 1
    since = np.where(last >= 0, t_frame - changes[np.maximum(last, 0)], np.inf)
    direction[since < SETTLE_S * 1e9] = 0.0
    u = np.array([m.displacement_mm for m in frames]) * PX_PER_MM  # the tracker ran at the nominal scale
    return travel, direction, u


def calibrate(presses: Sequence[tuple[Press, float]], info: dict[str, object] | None = None) -> ProbeCalibration:
    """Fit a calibration from recorded presses: the first of ``presses`` is the rigid flat (K = inf)."""
    (rigid, k_rigid), *springs = presses
    if not math.isinf(k_rigid) or not springs:
        raise CalibrationError("calibrate: need the rigid flat first, then at least one reference spring")
    travel, direction, u = _series(rigid)
    polys, contact = fit_scale(travel, u, direction, min_u_px=8.0)
    cal = ProbeCalibration(polys, (1.0,) * len(polys))
    ks, ses = [], []
    for press, k_ref in springs:
        travel, direction, u = _series(press)
        k_j, se_j = fit_springs(travel, cal.to_mm(u), direction, k_ref)
        ks.append(k_j)
        ses.append(se_j)
    weight = 1.0 / np.maximum(np.asarray(ses), 1e-12) ** 2  # each reference by its precision
    k = np.sum(weight * np.asarray(ks), axis=0) / np.sum(weight, axis=0)
    notes = dict(info or {})
    notes.update({"contact_travel_mm": [round(float(c), 4) for c in contact],
                  "k_per_reference": {str(kr): [round(float(v), 5) for v in kk]
                                      for (_, kr), kk in zip(springs, ks, strict=True)}})
    return ProbeCalibration(polys, tuple(float(v) for v in k), 1.0, notes)


def press_reference(phantom: str, *, device_seed: int, seed: int = 0, depth_mm: float = 9.0,
                    speed_mm_s: float = 1.5, cycles: int = 4, ideal: bool = False) -> Press:
    """One simulated reference press of the linear stage (in-process graph): the poses and indenter frames."""
    from nodes.probe.camera_tracker import CameraTracker
    from nodes.scanner.linear_stage import LinearStage
    from palpa.testing import GraphHarness

    g = GraphHarness()
    stage = g.add(LinearStage, {"phantom": phantom, "depth_mm": depth_mm, "speed_mm_s": speed_mm_s, "hold_s": 0.5,
                                "settle_s": 1.2, "dwell_s": 0.3, "cycles": cycles})
    g.add(CameraTracker, {"phantom": phantom, "seed": seed, "device_seed": device_seed,
                          "sim_errors": "ideal" if ideal else "realistic"})
    g.advance(1.3 + cycles * stage.profile.cycle_s)
    out = (g.published("robot/pose", RobotPose), g.published("camera/indenters", IndenterDisplacements))
    g.close()
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """CLI: calibrate a simulated probe and write the file."""
    ap = argparse.ArgumentParser(prog="python -m tools.camera_calibrate", description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", required=True, help="calibration file to write (YAML)")
    ap.add_argument("--device-seed", type=int, default=0, help="which simulated probe (the sim camera's device_seed)")
    ap.add_argument("--seed", type=int, default=100, help="image-noise seed of the calibration presses")
    args = ap.parse_args(argv)
    presses = [(press_reference(path, device_seed=args.device_seed, seed=args.seed + i, depth_mm=depth,
                                speed_mm_s=speed), k) for i, (path, k, depth, speed) in enumerate(REFERENCES)]
    try:
        cal = calibrate(presses, {"device_seed": args.device_seed, "references": [
            {"phantom": Path(p).name, "label_n_per_mm": None if math.isinf(k) else k, "depth_mm": d}
            for p, k, d, _ in REFERENCES]})
    except CalibrationError as exc:
        print(f"camera_calibrate: {exc}", file=sys.stderr)
        return 1
    Path(args.output).write_text("# camera-probe calibration (python -m tools.camera_calibrate)\n"
                                 + yaml.safe_dump(cal.to_dict(), sort_keys=False))
    print(json.dumps({"output": args.output, "k_n_per_mm": cal.k_n_per_mm, "scale_poly": cal.scale_poly}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
