"""The documented UR-emulator recipe (launch/scan_ur.yaml's header) over the specimen's edge (issue 39): its fixed
2-58 mm raster of the 60 mm phantom ran the SPS ring off the specimen at every line's ends, read 100-300 kPa there
and reported one 16.9 mm "tumour" at x11 with exit 0. Through the UR emulator (ur_rtde, real time), a raster whose
first lines run the ring past the measured edge: those readings are not mapped, and as most of the raster's are,
the map says it cannot be trusted (the launch then fails)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from emulators.clock_file import ClockWriter
from tests.procs import ur_emulator
from tests.test_scan_e2e import UR_OFFSET, scan_in_harness

pytestmark = pytest.mark.system


@pytest.mark.xdist_group("ur-emulator")  # real-time emulator: one at a time
@pytest.mark.timeout(150)
def test_the_ur_recipe_maps_no_reading_whose_ring_hangs_off_the_specimen(tmp_path: Path) -> None:
    home = [h + o for h, o in zip((2.0, 12.0, 9.0), UR_OFFSET, strict=True)]
    writer = ClockWriter(tmp_path / "clock")
    try:
        with ur_emulator(["--unlock-delay", "0", "--home", ",".join(map(str, [*home, 0, math.pi, 0])),
                          "--clock-file", str(writer.path)]) as emu:
            # lines at x = 2, 5 and 8 mm (the ring's 6 mm radius past the phantom's x = 0 edge on the first two)
            scan_in_harness(tmp_path / "ur", [f"robot_host:={emu.host}", "region_mm:=[2.0, 12.0, 8.0, 24.0]",
                                              "home_mm:=[2.0, 12.0, 9.0]"], timeout_s=60, clock=writer)
    finally:
        writer.close()
    with np.load(tmp_path / "ur" / "map" / "map.npz") as m:
        xs, k = m["x_mm"], m["stiffness"]
        why = str(m["incomplete"]) if "incomplete" in m else ""
    assert np.isnan(k[:, xs < 5.5]).all(), k  # the lines at x = 2 and 5: not one cell mapped
    assert np.isfinite(k[:, np.abs(xs - 8.0) < 1.5]).any(), k  # the line at x = 8 is (the ring on the specimen)
    assert "ring_off_specimen" in why and "the map cannot be trusted" in why, why
