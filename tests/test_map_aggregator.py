"""Map aggregator node: bins samples, detects inclusions, writes the three files of DESIGN.md."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from messages import ScanPlan, ScanStatus, StiffnessSample, Trigger
from nodes.mapping.map_aggregator import MapAggregator
from palpa.node.service import RequestRefused
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
    # its significance and false-alarm probability, and the threshold it passed, ride on map/inclusions
    assert inc.snr > final.threshold_snr > 0 and 0 <= inc.false_alarm < 1e-6 and final.false_alarm_per_map == 0.003

    data = np.load(tmp_path / "map.npz")
    # the plan's region plus half a cell each side, so that samples on the region's edges sit in cell centres
    assert data["stiffness"].shape == (21, 21) and data["x_mm"][0] == 0.0 and data["x_mm"][-1] == 40.0
    assert data["count"].sum() == 1600 and str(data["unit"]) == "kPa"
    records = json.loads((tmp_path / "inclusions.json").read_text())
    assert list(records[0]) == ["x_mm", "y_mm", "radius_mm", "contrast", "snr", "false_alarm"]
    assert records[0]["snr"] == inc.snr
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
                "saved": "the scan did not finish: last heard scanning at 50 % of its path",
                "ctrl-c": "the scan did not finish: last heard scanning at 50 % of its path"}
    for out, states in (("done", ("scanning", "done")), ("fault", ("scanning", "fault")), ("probes", ("idle",)),
                        ("saved", ("scanning",)), ("ctrl-c", ("scanning",))):
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
        # a final map of part of a scan fails the node, whatever stopped the scan (a fault, Ctrl-C): the launch
        # cannot end clean with it; a map saved mid-scan is not final
        assert h.node.exit_code == (0 if out in ("done", "probes", "saved") else 1), out
        if out == "saved":
            h.close()  # stopped mid-scan after the save: nothing new to write, still only part of the scan
            assert h.node.exit_code == 1


def test_estimates_that_stop_coming_mid_scan_leave_the_map_incomplete_and_failed(tmp_path: Path) -> None:
    """The estimator killed mid-scan: the scan runs on to its end, but the map holds only its first part. The map
    notices by the scan's progress (no estimate, valid or not, over a stretch of the path), not by who died: it says
    over which part of the path none came, and fails. Estimates that keep coming (invalid ones too: the probe off
    the tissue between lines) are a complete map; a stretch without them that ends is still a hole."""
    plan = ScanPlan(stamp_ns=0, mode="sweep", region_mm=(0.0, 0.0, 20.0, 20.0), spacing_mm=2.0, speed_mm_s=10.0,
                    lines=10, estimated_duration_s=20.0, waypoints=[])
    cases = {"complete": (lambda p: True, ""),
             "killed": (lambda p: p < 0.195,
                        "no stiffness estimate came from 19 % to 100 % of the scan's path (did the estimator stop?)"),
             "hole": (lambda p: not 0.4 <= p < 0.6,
                      "no stiffness estimate came from 39 % to 60 % of the scan's path (did the estimator stop?)")}
    for out, (alive, why) in cases.items():
        h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / out)})
        h.publish("robot/plan", plan)
        for i in range(101):  # 20 s of scanning, the status at 5 Hz, estimates at 10 Hz while the estimator lives
            progress = i / 100
            h.publish("robot/scan_status", ScanStatus(stamp_ns=h.clock.now_ns(), state="scanning", line=i // 10,
                                                      lines=10, progress=progress, eta_s=0.0))
            for _ in range(2):
                if alive(progress):
                    h.publish("stiffness/sample", sample(progress * 20, 5.0, 26.0, valid=i % 3 != 0))
                h.advance(0.1)
        h.publish("robot/scan_status", ScanStatus(stamp_ns=h.clock.now_ns(), state="done", line=10, lines=10,
                                                  progress=1.0, eta_s=0.0))
        with np.load(tmp_path / out / "map.npz") as grid:
            assert (str(grid["incomplete"]) if "incomplete" in grid else "") == why, out
        assert h.node.exit_code == (1 if why else 0), out
        h.close()


def test_a_map_whose_raster_readings_were_mostly_excluded_cannot_be_trusted(tmp_path: Path) -> None:
    """The UR recipe's raster ran its ring off the specimen at every line's ends: readings that are not stiffness
    readings (invalid but for being in the air) are dropped from the map, and when more than ``max_excluded`` of
    the raster's readings in contact were, the map says why it cannot be trusted and fails. Readings in the air
    between lines (``no_contact``) and the touch-off's do not count."""
    for out, off_share in (("ok", 0.1), ("edges", 0.35)):
        h = NodeHarness(MapAggregator, {"output_dir": str(tmp_path / out), "region_mm": [0, 0, 20, 20]})
        h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state="touching", line=0, lines=10, progress=0.0,
                                                  eta_s=0.0))
        for _ in range(50):  # the touch-off's: not the raster's
            h.publish("stiffness/sample", StiffnessSample(stamp_ns=0, model="airfloat", x_mm=5, y_mm=5, z_mm=0,
                                                          value=math.nan, unit="kPa", valid=False,
                                                          reason="at_stroke_end"))
        h.publish("robot/scan_status", ScanStatus(stamp_ns=1, state="scanning", line=0, lines=10, progress=0.0,
                                                  eta_s=0.0))
        for i in range(200):
            x = (i % 20) + 0.5
            if i % 20 < 20 * off_share:
                s = StiffnessSample(stamp_ns=2, model="airfloat", x_mm=x, y_mm=5, z_mm=0, value=math.nan,
                                    unit="kPa", valid=False, reason="ring_off_specimen")
            else:
                s = StiffnessSample(stamp_ns=2, model="airfloat", x_mm=x, y_mm=5, z_mm=0, value=26.0, unit="kPa",
                                    valid=True)
            h.publish("stiffness/sample", s)
            h.publish("stiffness/sample", StiffnessSample(stamp_ns=2, model="airfloat", x_mm=x, y_mm=5, z_mm=0,
                                                          value=math.nan, unit="kPa", valid=False,
                                                          reason="no_contact"))  # in the air: not counted
            h.publish("stiffness/sample", StiffnessSample(  # nor the camera probe's, between its presses
                stamp_ns=2, model="multi_indenter", x_mm=x, y_mm=5, z_mm=0, value=math.nan, unit="kPa", valid=False,
                reason="too few indenters in contact (need 4): [] moved more than 1.0 mm"))
        h.publish("robot/scan_status", ScanStatus(stamp_ns=3, state="done", line=10, lines=10, progress=1.0,
                                                  eta_s=0.0))
        with np.load(tmp_path / out / "map.npz") as grid:
            why = str(grid["incomplete"]) if "incomplete" in grid else ""
            assert np.nanmax(grid["stiffness"]) < 30  # what was excluded is not in the map
        if out == "ok":
            assert why == "" and h.node.exit_code == 0
        else:
            assert why == ("35 % of the raster's readings in contact were not stiffness readings "
                           "(ring_off_specimen 70; at most 20 % may be): the map cannot be trusted")
            assert h.node.exit_code == 1
        h.close()


def test_each_probe_s_maps_are_detected_with_that_probe_s_false_alarm_law(tmp_path: Path, caplog) -> None:  # type: ignore[no-untyped-def]
    """The camera probe's samples (model multi_indenter) are thresholded with the law measured on its blank scans,
    not the air-float's; map.npz keeps the model, so a redetection (tools' --redetect) uses the same law; a probe
    with no measured law gets the air-float's, with a warning that says so."""
    from dataclasses import replace

    from models.detector import DetectorConfig, detect, false_alarm_law
    from nodes.mapping.map_output import map_model, read_map, redetect

    rng = np.random.default_rng(5)
    thresholds = {}
    for model in ("multi_indenter", "airfloat", "someone_elses"):
        out = tmp_path / model
        caplog.clear()
        h = NodeHarness(MapAggregator, {"output_dir": str(out), "region_mm": [0, 0, 48, 48], "resolution_mm": 4.0})
        for x in np.arange(2.0, 48, 4.0):
            for y in np.arange(2.0, 48, 4.0):
                for _ in range(3):
                    h.publish("stiffness/sample", StiffnessSample(
                        stamp_ns=0, model=model, x_mm=float(x), y_mm=float(y), z_mm=0.0,
                        value=0.15 * math.exp(rng.normal(0, 0.03)), unit="N/mm", valid=True))
        h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state="done", line=1, lines=1, progress=1.0, eta_s=0))
        thresholds[model] = h.published("map/inclusions")[-1].threshold_snr
        h.close()
        assert map_model(out / "map.npz") == model
        own = false_alarm_law(model) or DetectorConfig().gumbel
        assert thresholds[model] == detect(read_map(out / "map.npz"), replace(DetectorConfig(), gumbel=own)).threshold_snr
        assert redetect(out / "map.npz").threshold_snr == thresholds[model]
        warned = "no false-alarm law was measured for 'someone_elses' maps" in caplog.text
        assert warned == (model == "someone_elses")
    assert thresholds["multi_indenter"] != thresholds["airfloat"] == thresholds["someone_elses"]


def test_a_map_that_cannot_be_written_ends_the_node_non_zero_saying_why(tmp_path: Path,
                                                                      caplog: pytest.LogCaptureFixture) -> None:
    """A full disk or a read-only folder at the end of a scan: the write failed inside the status callback, was
    logged as a bare traceback, and the node ended 0, a scan without a map reported clean. Here the output folder lies
    under a file: the node says where and why, its exit code is 1 (after the scan's end and again at shutdown), and
    ``map/save`` is refused with the reason instead of answering with no paths."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    out = blocker / "map"
    h = NodeHarness(MapAggregator, {"output_dir": str(out), "region_mm": [0, 0, 10, 10]})
    for x in range(10):
        h.publish("stiffness/sample", sample(x + 0.5, 5.0, 26.0))
    with caplog.at_level(logging.ERROR):
        h.publish("robot/scan_status", ScanStatus(stamp_ns=0, state="done", line=5, lines=5, progress=1.0, eta_s=0))
    assert h.node.written == 0 and h.node.exit_code == 1
    assert any(f"the map could not be written to {out}" in r.getMessage() for r in caplog.records)
    with pytest.raises(RequestRefused, match="could not be written"):
        h.node.on_save(Trigger())
    h.close()
    assert h.node.exit_code == 1
