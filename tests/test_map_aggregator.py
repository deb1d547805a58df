"""Map aggregator node: bins samples, detects inclusions, writes the three files of DESIGN.md."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from messages import ScanPlan, ScanStatus, StiffnessSample, Trigger
from nodes.mapping.map_aggregator import MapAggregator
from palpa.testing import MemoryBus, NodeHarness


def sample(x: float, y: float, v: float, valid: bool = True) -> StiffnessSample:
    return StiffnessSample(stamp_ns=0, model="airfloat", x_mm=x, y_mm=y, z_mm=0.0, value=v, unit="kPa",
                           valid=valid, reason="" if valid else "no_contact")


def test_map_from_plan_region_detects_blob_and_writes_files(tmp_path: Path) -> None:
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path), "resolution_mm": 2.0, "title": "unit test"})
    h.publish("robot/plan", ScanPlan(stamp_ns=0, mode="sweep", region_mm=(0.0, 0.0, 40.0, 40.0), spacing_mm=2.0,
                                     speed_mm_s=10.0, lines=20, estimated_duration_s=1.0, waypoints=[]))
    rng = np.random.default_rng(3)
    for x in np.arange(0.5, 40, 1.0):
        for y in np.arange(0.5, 40, 1.0):
            v = 26.4 * (1 + 2.0 * math.exp(-((x - 12) ** 2 + (y - 25) ** 2) / (2 * 3.0**2)))
            h.publish("stiffness/sample", sample(float(x), float(y), v + rng.normal(0, 0.3)))
    h.publish("stiffness/sample", sample(5.0, 5.0, 1e6, valid=False))  # invalid: ignored
    h.advance(1.0)
    live = h.published("map/inclusions")[-1]
    assert not live.final and len(live.inclusions) == 1
    h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state="done", line=20, lines=20, progress=1.0, eta_s=0))
    final = h.published("map/inclusions")[-1]
    assert final.final and abs(final.baseline - 26.4) < 0.5
    inc = final.inclusions[0]
    assert math.hypot(inc.x_mm - 12, inc.y_mm - 25) < 1.0 and inc.contrast > 2.5

    data = np.load(tmp_path / "map.npz")
    # the plan's region plus half a cell each side, so that samples on the region's edges sit in cell centres
    assert data["stiffness"].shape == (21, 21) and data["x_mm"][0] == 0.0 and data["x_mm"][-1] == 40.0
    assert data["count"].sum() == 1600 and str(data["unit"]) == "kPa"
    records = json.loads((tmp_path / "inclusions.json").read_text())
    assert list(records[0]) == ["x_mm", "y_mm", "radius_mm", "contrast"]
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    m = h.published("map/stiffness")[-1]
    assert len(m.stiffness) == 441 and m.samples == 1600
    h.close()


def test_flat_map_has_no_inclusions(tmp_path: Path) -> None:
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path), "region_mm": [0, 0, 30, 30]})
    rng = np.random.default_rng(4)
    for x in np.arange(0.5, 30, 1.0):
        for y in np.arange(0.5, 30, 1.0):
            h.publish("stiffness/sample", sample(float(x), float(y), 26.4 + rng.normal(0, 1.0)))
    h.close()  # shutdown writes the final map too
    assert json.loads((tmp_path / "inclusions.json").read_text()) == []


def test_map_written_once_per_scan_and_not_again_on_shutdown(tmp_path: Path) -> None:
    """A replay repeats ``done`` 4-5 times and the launcher stops the node right after: one write, and a
    shutdown that has nothing new to save does not render the map again (that took the node past SIGINT)."""
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path), "region_mm": [0, 0, 10, 10]})
    done = ScanStatus(stamp_ns=0, state="done", line=5, lines=5, progress=1.0, eta_s=0)
    for x in range(10):
        h.publish("stiffness/sample", sample(x + 0.5, 5.0, 26.0))
    for _ in range(4):
        h.publish("robot/scan_status", done)
    assert h.node.written == 1
    assert [m.final for m in h.published("map/inclusions")].count(True) == 1
    h.close()
    assert h.node.written == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["inclusions.json", "map.npz", "map.png"]  # no temp files


def test_shutdown_writes_samples_taken_after_the_last_write(tmp_path: Path) -> None:
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path), "region_mm": [0, 0, 10, 10]})
    h.publish("stiffness/sample", sample(1.0, 1.0, 26.0))
    h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state="done", line=1, lines=1, progress=1.0, eta_s=0))
    h.publish("stiffness/sample", sample(3.0, 3.0, 26.0))  # a second scan stopped half-way
    h.close()
    assert h.node.written == 2
    assert int(np.load(tmp_path / "map.npz")["count"].sum()) == 2


def test_samples_of_the_touch_off_are_not_mapped(tmp_path: Path) -> None:
    """While the scanner touches off (finding the surface) the probe's estimates are not the raster's: dropped."""
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path), "region_mm": [0, 0, 10, 10]})

    def sample(t: int, value: float) -> None:
        h.publish("stiffness/sample", StiffnessSample(stamp_ns=t, model="airfloat", x_mm=5.0, y_mm=5.0, z_mm=0.0, value=value, unit="kPa",
                                                      valid=True))

    h.publish("robot/scan_status", ScanStatus(stamp_ns=10, state="touching", line=0, lines=1, progress=0.0,
                                              eta_s=0.0))
    sample(11, 99.0)
    h.publish("robot/scan_status", ScanStatus(stamp_ns=20, state="scanning", line=0, lines=1, progress=0.0,
                                              eta_s=0.0))
    sample(15, 98.0)  # measured during the touch-off, arriving late
    sample(21, 26.0)
    assert h.node.samples == 1


def _raw_sample(seq: int, inc: int, x: float) -> list[bytes]:
    import msgspec

    header = msgspec.msgpack.encode({"type": "StiffnessSample", "seq": seq, "stamp": 1, "node": "estimator",
                                     "inc": inc})
    return [b"stiffness/sample", header, msgspec.msgpack.encode(sample(x, 5.0, 26.0))]


def test_a_map_that_missed_samples_is_declared_failed(tmp_path: Path) -> None:
    plan = ScanPlan(stamp_ns=0, mode="sweep", region_mm=(0.0, 0.0, 20.0, 20.0), spacing_mm=2.0, speed_mm_s=10.0,
                    lines=10, estimated_duration_s=1.0, waypoints=[])
    done = ScanStatus(stamp_ns=0, state="done", line=10, lines=10, progress=1.0, eta_s=0)
    # complete: exit code 0
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / "ok")})
    h.publish("robot/plan", plan)
    for seq in range(1, 11):
        h.publish_raw(_raw_sample(seq, 7, float(seq)))
    h.publish("robot/scan_status", done)
    assert h.node.exit_code == 0 and not h.node.incomplete
    h.close()
    # the estimator restarted mid-scan (a new incarnation): what it held is lost
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / "est")})
    h.publish("robot/plan", plan)
    for inc, n in ((7, 10), (8, 5)):
        for seq in range(1, n + 1):
            h.publish_raw(_raw_sample(seq, inc, float(seq)))
    h.publish("robot/scan_status", done)
    assert h.node.exit_code == 1 and "restarted 1 time" in h.node.incomplete
    h.close()
    # the map itself restarted: the bus still holds its previous incarnation's latched, unfinished map
    bus = MemoryBus()
    first = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / "map1")}, name="map", bus=bus)
    first.publish("robot/plan", plan)
    for seq in range(1, 11):
        first.publish_raw(_raw_sample(seq, 7, float(seq)))
    first.advance(1.0)  # publishes the (latched) map
    for node in (first.node, first._probe):  # killed: no final map, its transport just goes away
        node.transport.close(0)
    h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / "map2")}, name="map", bus=bus)
    h.publish("robot/plan", plan)
    for seq in range(11, 15):
        h.publish_raw(_raw_sample(seq, 7, float(seq)))
    h.publish("robot/scan_status", done)
    assert h.node.exit_code == 1 and "restarted mid-scan" in h.node.incomplete and "10 samples" in h.node.incomplete
    h.close()


def test_a_map_written_before_its_scan_is_done_says_how_far_the_scan_got(tmp_path: Path) -> None:
    """A scan stopped half-way by a fault: the map written as the node stops says that the scan did not finish, how
    far it got and why (map.npz's ``incomplete``, map.png's title). A scan that is done writes no such note, nor a
    scanner serving probes (never scanning); a map saved mid-scan says it is part of one."""
    plan = ScanPlan(stamp_ns=0, mode="sweep", region_mm=(0.0, 0.0, 20.0, 20.0), spacing_mm=2.0, speed_mm_s=10.0,
                    lines=10, estimated_duration_s=1.0, waypoints=[])
    why = "pressure/state silent for more than 500 ms"
    expected = {"done": "", "probes": "",
                "fault": f"the scan did not finish: it ended fault at 50 % of its path ({why})",
                "saved": "the scan did not finish: last heard scanning at 50 % of its path"}
    for out, states in (("done", ("scanning", "done")), ("fault", ("scanning", "fault")), ("probes", ("idle",)),
                        ("saved", ("scanning",))):
        h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / out)})
        h.publish("robot/plan", plan)
        for seq in range(1, 11):
            h.publish_raw(_raw_sample(seq, 7, float(seq)))
        for state in states:
            h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state=state, line=5, lines=10,
                                                      progress=1.0 if state == "done" else 0.5, eta_s=0.0,
                                                      message=why if state == "fault" else ""))
        if out == "saved":
            h.node.on_save(Trigger())
        else:
            h.close()  # the node stops: what no file holds yet is written
        with np.load(tmp_path / out / "map.npz") as grid:
            assert (str(grid["incomplete"]) if "incomplete" in grid else "") == expected[out]
        assert h.node.exit_code == 0  # what it did receive is all there: the scanner's own exit says the fault
        if out == "saved":
            h.close()
