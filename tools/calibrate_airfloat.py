"""Calibrate the air-float probe: ``python -m tools.calibrate_airfloat -o calibration.yaml [--seed N]``.

The procedure a user runs on the bench (docs/physics.md, "Calibration"), here against the simulated devices:

1. **Force line.** The probe presses on a force sensor while the regulator cycles 30 -> 46 -> 30 kPa three
   times; eq. 4's line is fitted to (read-back kPa, sensor N). On the rig, give the logged pairs instead:
   ``--plate-csv FILE`` (two columns: kPa, N).
2. **Reference samples.** For each ``--reference PHANTOM:MODULUS:GEOMETRY`` (default: the paper's 26.4 and
   10.8 kPa flat samples with their measured thickness files), the probe is held 1 mm above the sample while the
   pressure ramps through 1-3 mm of indentation; the real nodes (regulator, fibre reader) run in-process on a
   simulated clock and the calibration sees only their topics. A depth offset and a force offset are fitted so
   that eq. 7 returns the certified moduli.

The calibration file is what the pressure controller and the estimator load (``calibration:`` param). The
simulated devices are drawn from ``--seed``: calibrate with the seed the scan's drivers use (the same physical
probe).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from messages import PressureCommand, PressureState, ProbeHeights
from models.airfloat import DEFAULT_INDENTER_RADIUS_MM, ForceCalibration
from models.airfloat_device import ProbeErrors, TrueProbe
from models.calibration_airfloat import (
    AirfloatCalibration,
    CalibrationError,
    ReferenceRamp,
    fit_force_line,
    fit_references,
    save_calibration,
)
from models.contact import corrected_force
from models.geometry import load_geometry

REPO = Path(__file__).resolve().parent.parent
DEFAULT_REFERENCES = [f"{REPO}/phantoms/flat_26k.yaml:26.4:{REPO}/phantoms/measured/flat_26k.yaml",
                      f"{REPO}/phantoms/flat_10k.yaml:10.8:{REPO}/phantoms/measured/flat_10k.yaml"]
_CENTRE = (30.0, 30.0)


@dataclass(frozen=True)
class Reference:
    phantom: str
    modulus_kpa: float
    geometry: str

    @classmethod
    def parse(cls, text: str) -> Reference:
        parts = text.rsplit(":", 2)
        if len(parts) != 3:
            raise CalibrationError(f"--reference {text!r}: expected PHANTOM:MODULUS_KPA:GEOMETRY")
        try:
            return cls(parts[0], float(parts[1]), parts[2])
        except ValueError:
            raise CalibrationError(f"--reference {text!r}: modulus {parts[1]!r} is not a number") from None


def sim_force_plate(seed: int, cycles: int = 3, noise_n: float = 0.003) -> tuple[np.ndarray, np.ndarray]:
    """(read-back kPa, plate N) from the simulated regulator and a force sensor under the simulated probe."""
    from nodes.probe.pressure_controller import PressureController
    from palpa.testing import GraphHarness

    probe = TrueProbe(ProbeErrors.draw(seed))
    rng = np.random.default_rng([seed, 2])
    with GraphHarness() as g:
        g.add(PressureController, {"startup": "hold", "setpoint_kpa": 30.0, "seed": seed + 1000})
        g.advance(1.0)
        for _ in range(cycles):
            for target in (46.0, 30.0):
                g.publish("pressure/command", PressureCommand(mode="ramp", setpoint_kpa=target, rate_kpa_s=4.0))
                g.advance(4.5)
        states = [s for s in g.published("pressure/state", PressureState) if s.mode == "ramp"]
    p = np.array([s.measured_kpa for s in states])
    rising = np.gradient(np.array([s.setpoint_kpa for s in states])) > 0
    f = np.asarray(probe.tissue_force_n(probe.probe_pressure_kpa(p), rising), dtype=float)
    return p, f + rng.normal(0.0, noise_n, f.shape)


def sim_reference_ramp(ref: Reference, seed: int, target_kpa: float) -> ReferenceRamp:
    """Hold the probe 1 mm above a reference sample and ramp the pressure; d_in and read-back kPa by stamp."""
    from nodes.probe.fibre_reader import FibreReader
    from nodes.probe.pressure_controller import PressureController
    from nodes.scanner.static_pose import StaticPose
    from palpa.testing import GraphHarness

    thickness = float(load_geometry(ref.geometry).thickness(*_CENTRE))
    with GraphHarness() as g:
        g.add(StaticPose, {"x_mm": _CENTRE[0], "y_mm": _CENTRE[1], "z_mm": thickness + 1.0})
        g.add(PressureController, {"startup": "hold", "setpoint_kpa": 30.0, "seed": seed + 1000})
        g.add(FibreReader, {"phantom": ref.phantom, "device_seed": seed})
        g.advance(1.0)
        g.publish("pressure/command", PressureCommand(mode="ramp", setpoint_kpa=target_kpa, rate_kpa_s=2.0))
        g.advance((target_kpa - 30.0) / 2.0 + 0.5)
        heights = g.published("probe/heights", ProbeHeights)
        states = g.published("pressure/state", PressureState)
    ts = np.array([s.stamp_ns for s in states], dtype=float)
    kpa = np.array([s.measured_kpa for s in states])
    hs = np.array([h.stamp_ns for h in heights], dtype=float)
    d = np.array([h.d_in_mm for h in heights])
    inside = (hs >= ts[0]) & (hs <= ts[-1])
    return ReferenceRamp(ref.modulus_kpa, thickness, np.interp(hs[inside], ts, kpa), d[inside])


def _ramp_target(line: ForceCalibration, modulus_kpa: float, thickness_mm: float) -> float:
    """The pressure that should reach 3 mm (the paper's maximum) on this sample by eq. 7 and the fitted line: the
    operator's rule of thumb for where to stop the ramp."""
    force = float(corrected_force(modulus_kpa, 3.0, DEFAULT_INDENTER_RADIUS_MM, thickness_mm))
    return float(line.pressure_kpa(force))


def calibrate(seed: int, references: list[Reference], plate_csv: Path | None = None) -> AirfloatCalibration:
    """Run both steps and return the calibration (module doc)."""
    if plate_csv is not None:
        data = np.loadtxt(plate_csv, delimiter=",", ndmin=2)
        p, f = data[:, 0], data[:, 1]
    else:
        p, f = sim_force_plate(seed)
    line, rmse = fit_force_line(p, f)
    ramps = [sim_reference_ramp(r, seed, _ramp_target(line, r.modulus_kpa, float(
        load_geometry(r.geometry).thickness(*_CENTRE)))) for r in references]
    delta, df, rel = fit_references(line, ramps, indenter_radius_mm=DEFAULT_INDENTER_RADIUS_MM)
    force = ForceCalibration(line.gain, line.offset + df, line.pressure_unit_kpa)
    names = ", ".join(f"{Path(r.phantom).stem} ({r.modulus_kpa:g} kPa)" for r in references)
    return AirfloatCalibration(force=force, depth_offset_mm=delta, force_line_rmse_n=rmse, reference_rms_rel=rel,
                               source=f"tools.calibrate_airfloat, sim probe seed {seed}; references: {names}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.calibrate_airfloat", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0, help="the simulated probe (the fibre reader's device_seed)")
    ap.add_argument("--reference", action="append", help="PHANTOM:MODULUS_KPA:GEOMETRY (repeat)")
    ap.add_argument("--plate-csv", type=Path, help="rig: logged (kPa, N) pairs from the force sensor")
    args = ap.parse_args(argv)
    try:
        refs = [Reference.parse(t) for t in (args.reference or DEFAULT_REFERENCES)]
        cal = calibrate(args.seed, refs, args.plate_csv)
    except (CalibrationError, OSError, ValueError) as exc:
        print(f"calibrate_airfloat: {exc}", file=sys.stderr)
        return 1
    save_calibration(args.output, cal)
    print(f"force line F = {cal.force.gain:.4f} P[bar] {cal.force.offset:+.4f} N (RMSE {cal.force_line_rmse_n:.4f} N);"
          f" depth offset {cal.depth_offset_mm:+.4f} mm; reference residual {100 * cal.reference_rms_rel:.1f} %"
          f" -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
