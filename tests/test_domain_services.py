"""The palpation graph's services on the in-memory bus: probe_at returns the phantom's stiffness at the point,
pause/resume/abort of a scan, a pressure set-point never above the cap, tare, save the map now."""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

import pytest

import palpa
from messages import (
    MapSaved,
    PressureAck,
    ProbeAt,
    ProbeResult,
    SetPressure,
    StiffnessSample,
    Trigger,
    TriggerResult,
)
from models.phantom import load_phantom
from nodes.mapping.map_aggregator import MapAggregator
from nodes.probe.fibre_reader import FibreReader
from nodes.probe.pressure_controller import PressureController
from nodes.probe.stiffness_estimator import AirfloatStiffnessEstimator
from nodes.scanner.robot_scanner import RobotScanner
from palpa.node.service import BadRequestError, RequestRefused
from palpa.node.service_client import Future
from palpa.testing import GraphHarness, NodeHarness
from tests.test_robot_scanner import SMALL, run_with_probe

PHANTOM = "phantoms/airfloat_tumours.yaml"


def until_done(g: GraphHarness, fut: Future[Any], limit_s: float, step_s: float = 0.1) -> None:
    t = 0.0
    while not fut.done() and t < limit_s:
        g.advance(step_s)
        t += step_s
    assert fut.done(), f"no reply within {limit_s} s of simulated time"


def calibration() -> str:
    """The simulated probe calibrated on the bench (once per session)."""
    from tests.conftest import airfloat_calibration

    return str(airfloat_calibration())


def probe_graph(phantom: str = PHANTOM, kpa: float = 36.0, z: float = 5.0) -> tuple[GraphHarness, palpa.Node]:
    g = GraphHarness()
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": kpa, "max_kpa": 60.0,
                               "calibration": calibration()})
    g.add(FibreReader, {"phantom": phantom})
    g.add(AirfloatStiffnessEstimator, {"geometry": phantom.replace("phantoms/", "phantoms/measured/"),
                                       "calibration": calibration()})
    g.add(RobotScanner, {"autostart": False, "home_mm": [28.0, 28.0, 40.0], "watchdog_s": 0.5,
                         "speed_mm_s": 20.0, "contact_z_mm": z})
    op = g.add(palpa.Node, name="operator")
    g.advance(0.1)  # the probe's reader has heard a pose and sends heights
    return g, op


@pytest.mark.parametrize(("phantom", "kpa", "z", "x", "y"), [
    (PHANTOM, 36.0, 5.0, 30.0, 30.0), (PHANTOM, 36.0, 5.0, 8.0, 50.0),
    ("phantoms/flat_10k.yaml", 33.5, 21.0, 30.0, 30.0),  # a 20 mm thick block: the probe slides 1 mm above it
])
def test_probe_at_returns_the_phantoms_stiffness_within_10_percent(phantom: str, kpa: float, z: float, x: float,
                                                                   y: float) -> None:
    """Healthy tissue of two phantoms of different moduli, compared with the phantom's modulus at the point (until
    the FE-grounded world of issue 14 gives the truth under an inclusion: there the probe reads an effective
    modulus between the surface's and the buried inclusion's, which the phantom file does not state)."""
    g, op = probe_graph(phantom, kpa, z)
    probe = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60)
    fut = probe.call_async(ProbeAt(x_mm=x, y_mm=y))
    until_done(g, fut, 20.0)
    r = fut.result()
    truth = float(load_phantom(phantom).youngs_modulus(x, y))
    assert r.unit == "kPa" and r.samples >= 20
    assert abs(r.value / truth - 1) < 0.10, (r, truth)
    assert [s.state for s in g.published("robot/scan_status")][-1] == "idle"
    assert any(s.state == "probing" for s in g.published("robot/scan_status"))  # progress on the topic
    g.close()


def test_probe_over_an_inclusion_reads_stiffer_than_healthy_tissue() -> None:
    g, op = probe_graph()
    probe = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60)
    fut = probe.call_async(ProbeAt(x_mm=15.0, y_mm=18.0))
    until_done(g, fut, 20.0)
    # issue 14's FE reference: a 6 mm x6 cylinder 2 mm under a 3.68 mm layer pushes back 1.5-1.6x harder at
    # equal depth, which eq. 7 reads as ~1.7x the modulus (BENCHMARKS.md: the demo scan's peak is 1.65)
    ratio = fut.result().value / float(load_phantom(PHANTOM).youngs_modulus(30.0, 30.0))
    assert 1.45 < ratio < 2.0, ratio
    g.close()


def test_a_probe_answers_from_its_measuring_part_only_not_from_the_descent_or_the_retract() -> None:
    """The air-float probe's floating indenter reaches the tissue from up to ~9 mm above the working height and
    reads it there at another load: with a radius that takes in the line's ends, the descent onto the line and the
    retract are heard near the point too, and left out of the answer."""
    g, op = probe_graph()
    fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(
        ProbeAt(x_mm=30.0, y_mm=30.0, radius_mm=4.0))
    until_done(g, fut, 20.0)
    r = fut.result()
    near = [s for s in g.published("stiffness/sample") if s.valid and math.dist((s.x_mm, s.y_mm), (30.0, 30.0)) <= 4]
    down = [s.value for s in near if abs(s.z_mm - 5.0) < 0.05]  # measured at the working height (contact_z_mm)
    # the premise: most estimates near the point came from above it, and they read higher
    assert len(near) > 2 * len(down) and statistics.median(s.value for s in near) > 1.03 * statistics.median(down)
    assert 0.9 * len(down) <= r.samples <= len(down), (r.samples, len(down), len(near))
    assert r.value == pytest.approx(statistics.median(down), rel=0.003)
    # the answer says when it measured, so that a caller binning the estimates itself (the adaptive planner) keeps
    # the same ones: the working height's inside that span, the descent's and the retract's outside it
    def inside(t: int) -> bool:
        return r.measured_from_ns <= t <= r.measured_to_ns

    up = [s for s in near if abs(s.z_mm - 5.0) >= 0.05]
    assert r.measured_from_ns > 0 and sum(inside(s.stamp_ns) for s in near if abs(s.z_mm - 5.0) < 0.05) == r.samples
    assert sum(inside(s.stamp_ns) for s in up) <= 0.1 * len(up), (len(up), sum(inside(s.stamp_ns) for s in up))
    g.close()


def test_a_shorter_rest_answers_sooner_with_the_same_estimates() -> None:
    """probe_rest_s is the earliest answer after the path's end, not a wait for the estimates (the answer waits for
    an estimate measured after the path's end whatever the rest): 0.1 s answers 0.5 s sooner than 0.6 s, from the
    same estimates."""
    results = {}
    for rest in (0.6, 0.1):
        g = GraphHarness()
        g.add(RobotScanner, {"autostart": False, "home_mm": [30.0, 26.0, 8.0], "watch_topic": "",
                             "contact_z_mm": 5.0, "speed_mm_s": 10.0, "probe_rest_s": rest})
        op = g.add(palpa.Node, name="operator")
        fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(
            ProbeAt(x_mm=30.0, y_mm=30.0, radius_mm=4.0))
        _lagging_estimator(g, fut, 0.0, 30.0)
        results[rest] = fut.result()
        g.close()
    slow, quick = results[0.6], results[0.1]
    assert quick.samples == slow.samples >= 10 and quick.value == slow.value, results
    assert quick.duration_s == pytest.approx(slow.duration_s - 0.5, abs=0.1), results


def test_probe_takes_the_estimates_near_the_point_only() -> None:
    """The estimator is played by the test: estimates 0.5 mm from the point say 30, those 4 mm away say 100."""
    g = GraphHarness()
    g.add(RobotScanner, {"autostart": False, "home_mm": [28.0, 28.0, 40.0], "watch_topic": ""})
    op = g.add(palpa.Node, name="operator")
    fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(ProbeAt(x_mm=30, y_mm=30))
    t = 0.0
    while not fut.done() and t < 20:
        for y, value in ((30.5, 30.0), (34.0, 100.0), (26.0, 100.0)):
            g.publish("stiffness/sample", StiffnessSample(stamp_ns=g.clock.now_ns(), model="airfloat", x_mm=30.0,
                                                          y_mm=y, z_mm=5.0, value=value, unit="kPa", valid=True))
        g.advance(0.05)
        t += 0.05
    r = fut.result()
    assert r.value == 30.0 and r.mad == 0.0 and r.samples > 10
    g.close()


def _lagging_estimator(g: GraphHarness, fut: Future[Any], lag_s: float, limit_s: float) -> None:
    """Play an estimator ``lag_s`` behind the arm (a busy machine's wall clock) until ``fut`` is answered: every
    50 ms an estimate measured ``lag_s`` ago where the arm was then, valid (30 kPa) where the probe was down at the
    contact height (5 mm), "no_contact" elsewhere."""
    t = 0.0
    while not fut.done() and t < limit_s:
        stamp = g.clock.now_ns() - int(lag_s * 1e9)
        poses = [q for q in g.published("robot/pose") if q.stamp_ns <= stamp]
        if poses:
            q = poses[-1]
            down = abs(q.z_mm - 5.0) < 0.1
            g.publish("stiffness/sample", StiffnessSample(
                stamp_ns=stamp, model="airfloat", x_mm=q.x_mm, y_mm=q.y_mm, z_mm=q.z_mm,
                value=30.0 if down else math.nan, unit="kPa", valid=down, reason="" if down else "no_contact"))
        g.advance(0.05)
        t += 0.05


def test_a_probe_waits_for_an_estimator_running_late_and_answers_with_the_whole_sweep() -> None:
    """The estimates of a 0.6 s sweep come 2 s late, after the 0.6 s rest at the path's end: the answer waits for
    the first estimate measured at or after the path's end and takes every estimate of the sweep, where answering
    after the rest alone would refuse (none yet)."""
    results = {}
    for lag in (0.0, 2.0):
        g = GraphHarness()
        g.add(RobotScanner, {"autostart": False, "home_mm": [30.0, 26.0, 8.0], "watch_topic": "",
                             "contact_z_mm": 5.0, "speed_mm_s": 10.0})
        op = g.add(palpa.Node, name="operator")
        fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(
            ProbeAt(x_mm=30.0, y_mm=30.0, radius_mm=4.0))
        _lagging_estimator(g, fut, lag, 30.0)
        results[lag] = fut.result()
        g.close()
    prompt, late = results[0.0], results[2.0]
    assert prompt.value == late.value == 30.0 and late.samples >= 10, results
    # the late answer holds every estimate of the sweep, as the prompt one does (the stand-in's probe is up, "no
    # contact", after the path's retract: the rest adds nothing here)
    assert late.samples == prompt.samples, results
    assert late.duration_s >= prompt.duration_s + 1.0, results


def test_a_probe_with_no_estimator_is_refused_once_its_wait_for_one_is_over() -> None:
    g = GraphHarness()
    g.add(RobotScanner, {"autostart": False, "home_mm": [28.0, 28.0, 40.0], "watch_topic": ""})
    op = g.add(palpa.Node, name="operator")
    fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=120).call_async(ProbeAt(x_mm=30, y_mm=30))
    until_done(g, fut, 60.0)
    with pytest.raises(RequestRefused, match="no valid stiffness estimate.*no estimate at all came"):
        fut.result()
    statuses = g.published("robot/scan_status")
    assert statuses[-1].state == "idle"
    g.close()


def test_probe_refusals_outside_the_box_and_while_busy() -> None:
    g = GraphHarness()
    g.add(RobotScanner, {"autostart": False, "home_mm": [28.0, 28.0, 40.0]})
    probe = g.add(palpa.Node, name="early").client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60)
    early = probe.call_async(ProbeAt(x_mm=30.0, y_mm=30.0))
    g.spin()
    with pytest.raises(RequestRefused, match="no fresh probe data on probe/heights"):
        early.result()
    g.close()
    g, op = probe_graph()
    probe = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60)
    bad = probe.call_async(ProbeAt(x_mm=200.0, y_mm=30.0))
    g.spin()
    with pytest.raises(RequestRefused, match="workspace"):
        bad.result()
    first = probe.call_async(ProbeAt(x_mm=30.0, y_mm=30.0))
    g.advance(0.2)
    second = probe.call_async(ProbeAt(x_mm=30.0, y_mm=30.0))
    g.spin()
    with pytest.raises(RequestRefused, match="probing"):
        second.result()
    abort = op.client("scanner/abort", Trigger, TriggerResult).call_async(Trigger())
    g.spin()
    assert abort.result().state == "idle"
    with pytest.raises(RequestRefused, match="aborted"):
        first.result()
    g.close()


def test_pause_resume_and_abort_a_scan() -> None:
    h = NodeHarness(RobotScanner, SMALL)
    op = h.add(palpa.Node, name="operator")
    pause, resume, abort = (op.client(f"scanner/{v}", Trigger, TriggerResult) for v in ("pause", "resume", "abort"))

    def call(c: Any) -> TriggerResult:
        fut = c.call_async(Trigger())
        h.spin()
        return fut.result()  # type: ignore[no-any-return]

    run_with_probe(h, 1.0)
    assert h.published("robot/scan_status")[-1].state == "scanning"
    assert call(pause).state == "paused"
    progress = h.published("robot/scan_status")[-1].progress
    run_with_probe(h, 1.0)
    assert h.published("robot/pose")[-1].speed_mm_s == 0.0  # stopped, and the watchdog does not mind
    assert h.published("robot/scan_status")[-1].progress == pytest.approx(progress, abs=0.02)
    with pytest.raises(RequestRefused, match="nothing to pause"):
        call(pause)
    assert call(resume).state == "scanning"
    run_with_probe(h, 1.0)
    assert h.published("robot/scan_status")[-1].progress > progress + 0.02
    assert call(abort).state == "stopped"
    run_with_probe(h, 1.0)
    assert h.node.is_shutdown and h.node.exit_code == 2
    h.close()


def test_pressure_setpoint_within_the_cap_and_refused_above() -> None:
    h = NodeHarness(PressureController, {"max_kpa": 40.0, "startup": "hold", "setpoint_kpa": 20.0})
    op = h.add(palpa.Node, name="operator")
    setp = op.client("pressure/set", SetPressure, PressureAck)

    def call(req: SetPressure) -> PressureAck:
        fut = setp.call_async(req)
        h.spin()
        return fut.result()

    assert call(SetPressure(setpoint_kpa=35.0)).setpoint_kpa == 35.0
    with pytest.raises(RequestRefused, match="above the cap 40"):
        call(SetPressure(setpoint_kpa=40.5))
    with pytest.raises(BadRequestError, match=">= 0"):
        call(SetPressure(setpoint_kpa=-1.0))
    h.advance(1.0)
    states = h.published("pressure/state")
    assert states[-1].setpoint_kpa == 35.0 and max(s.setpoint_kpa for s in states) <= 40.0
    assert "clamped" not in states[-1].faults
    ramp = call(SetPressure(setpoint_kpa=39.0, mode="ramp", rate_kpa_s=2.0))
    assert ramp.mode == "ramp" and ramp.target_kpa == 39.0 and ramp.setpoint_kpa < 39.0
    h.close()


def test_tare_and_save_map_now(tmp_path: Path) -> None:
    g = GraphHarness()
    g.add(FibreReader, {"phantom": PHANTOM})
    g.add(MapAggregator, {"output_dir": str(tmp_path / "map"), "region_mm": [0.0, 0.0, 10.0, 10.0]})
    op = g.add(palpa.Node, name="operator")
    tare = op.client("probe/tare", Trigger, TriggerResult).call_async(Trigger())
    save = op.client("map/save", Trigger, MapSaved)
    early = save.call_async(Trigger())
    g.spin()
    assert "tared" in tare.result().message
    with pytest.raises(RequestRefused, match="no map"):
        early.result()
    for i in range(10):
        g.publish("stiffness/sample", StiffnessSample(stamp_ns=i, model="airfloat", x_mm=5.0, y_mm=5.0, z_mm=0.0,
                                                      value=26.0, unit="kPa", valid=True))
    saved = save.call_async(Trigger())
    g.spin()
    out = saved.result()
    assert out.samples == 10 and sorted(Path(p).name for p in out.paths) == ["inclusions.json", "map.npz",
                                                                              "map.png"]
    assert all(Path(p).stat().st_size > 0 for p in out.paths)
    g.close()


@pytest.mark.system
def test_tare_over_the_serial_driver_zeroes_the_heights() -> None:
    """probe/tare on the real serial driver against the DAQ emulator ($ZERO): the current pose then reads the
    calibration's zero heights (0 mm), where it read 1.5/1.5/1.5/3.5 mm before."""
    from emulators.fibre_daq import FibreDaqEmulator, source_from_heights
    from models.fibre_calibration import load_calibration
    from tests.test_probe_nodes_serial import CAL, run_until

    cal = load_calibration(CAL)
    with FibreDaqEmulator(source_from_heights(cal, lambda t: (1.5, 1.5, 1.5, 3.5)), rate_hz=200) as emu:
        h = NodeHarness(FibreReader, {"driver": "serial", "port": emu.port, "calibration": CAL, "rate_hz": 200})
        try:
            run_until(h, lambda: len(h.published("probe/heights")) >= 20, 10, "first samples")
            assert h.published("probe/heights")[-1].h_mm[3] == pytest.approx(3.5, abs=0.05)
            tare = h.add(palpa.Node, name="operator").client("probe/tare", Trigger, TriggerResult).call_async(
                Trigger())
            h.spin()
            assert tare.result().message == "tared"
            n = len(h.published("probe/heights"))
            run_until(h, lambda: len(h.published("probe/heights")) > n + 10, 10, "samples after the tare")
            assert h.published("probe/heights")[-1].h_mm == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=0.05)
        finally:
            h.close()


def test_a_sweep_starts_from_the_end_of_its_line_nearer_the_arm() -> None:
    """A planner going down a column of short sweeps would otherwise travel past each line to come back up it."""
    for home_y, first_y in ((20.0, 27.0), (40.0, 33.0)):
        g = GraphHarness()
        g.add(RobotScanner, {"autostart": False, "home_mm": [30.0, home_y, 8.0], "watch_topic": "",
                             "contact_z_mm": 5.0, "speed_mm_s": 10.0})
        op = g.add(palpa.Node, name="operator")
        fut = op.client("scanner/probe_at", ProbeAt, ProbeResult, timeout_s=60).call_async(
            ProbeAt(x_mm=30.0, y_mm=30.0, radius_mm=4.0))
        _lagging_estimator(g, fut, 0.0, 30.0)
        assert fut.result().samples >= 10
        down = [q for q in g.published("robot/pose") if abs(q.z_mm - 5.0) < 0.05]
        assert down and down[0].y_mm == pytest.approx(first_y, abs=0.3), (home_y, down[0])
        assert down[-1].y_mm == pytest.approx(60.0 - first_y, abs=0.3), (home_y, down[-1])
        g.close()
