"""The adaptive planner node driving the real scanner, composed in memory (launch/scan_adaptive_sim.yaml, small)."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from messages import RobotPose, ScanStatus, StiffnessMap
from palpa.launch import load_launch, parse_overrides
from palpa.launch.compose import compose_plan
from palpa.node.node import Node
from palpa.timing.clock import MockClock
from palpa.timing.compose import Composition
from tests.procs import REPO

if TYPE_CHECKING:
    from nodes.scanner.adaptive_planner import AdaptivePlanner

# contact_z_mm is the flat height a probe would sweep at without a touch-off: far above the dome (3-4 mm thick here)
# reach_mm: 2 so that the detection rule has more than two sweeps' worth of tissue to cover in this small region
SMALL = ["region_mm:=[36.0, 33.0, 54.0, 51.0]", "initial:=2", "seed_spacing_mm:=0", "max_probes:=8", "contact_z_mm:=8.0",
         "reach_mm:=2.0",
         f"geometry:={REPO / 'phantoms' / 'measured' / 'airfloat_tumours.yaml'}"]
BOX_X_MAX = 46.0
"""The scanner's workspace ends here in these tests: the planner's points at x = 49.5 mm lie outside it."""


def _adaptive(tmp: Path) -> tuple[dict[str, Any], list[dict[str, float]], list[StiffnessMap], list[float]]:
    from palpa.targets import load_node_class

    plan = compose_plan(load_launch(REPO / "launch" / "scan_adaptive_sim.yaml", parse_overrides(SMALL),
                                    run_dir=tmp))
    clock = MockClock(1_700_000_000_000_000_000)
    comp = Composition(clock=clock, heartbeat_s=0)
    for n in json.loads(plan.nodes[0].cmd[-1])["nodes"]:  # type: ignore[index]
        if n["name"] == "scanner":
            n["params"]["workspace_mm"] = [-10.0, -10.0, 0.5, BOX_X_MAX, 70.0, 60.0]
            n["params"]["region_mm"] = [5.0, 5.0, 40.0, 40.0]   # its (unused) raster must fit the box too
        if n["name"] != "recorder":
            comp.add(load_node_class(n["target"]), n["name"], n["params"], required=n["required"])
    beliefs: list[StiffnessMap] = []
    watcher = comp.adopt(Node(name="watcher", transport=comp.transport(), clock=clock, heartbeat_s=0))
    watcher.subscribe("planner/mean", StiffnessMap, beliefs.append)
    state = [""]
    probing_z: list[float] = []
    watcher.subscribe("robot/scan_status", ScanStatus, lambda m: state.__setitem__(0, m.state))
    watcher.subscribe("robot/pose", RobotPose, lambda m: probing_z.append(m.z_mm) if state[0] == "probing" else None)
    assert comp.run(max_sim_s=300.0) == 1   # not clean: points were given up (the test below)
    out = tmp / "map"
    assert (out / "map.npz").exists()
    return (json.loads((out / "planner.json").read_text()), json.loads((out / "inclusions.json").read_text()),
            beliefs, probing_z)


@pytest.mark.system
def test_planner_probes_through_the_scanner_carries_on_after_refusals_and_is_deterministic(tmp_path: Path) -> None:
    """Requests outside the scanner's box are refused by the scanner (the planner never checks the box itself);
    the planner gives those points up and spends its budget on the rest; it publishes its belief after each
    probe and writes the map; the same seed gives the same probe sequence and the same inclusions."""
    a, inc_a, beliefs, probing_z = _adaptive(tmp_path / "a")
    assert a["refused"] >= 3                                    # a point past x = 46 refused, retried twice, given up
    assert a["probes"] >= 3                                     # and it carried on
    assert all(p[0] < BOX_X_MAX for p in a["points"]) and len(a["points"]) == a["probes"]
    assert a["given_up"] and all(p[0] > BOX_X_MAX for p in a["given_up"])
    assert a["refused"] == 3 * len(a["given_up"])               # each given up after exactly its retries
    # a run that lost probes does not end clean: the planner exits 1 (above) and says what is missing
    assert a["incomplete"].startswith(f"{len(a['given_up'])} probe(s) given up after refusals, at ({a['given_up'][0][0]:.1f}, ")
    # every probe says why it was made: the coarse pass first, then what the acquisition chose it for
    assert len(a["why"]) == a["probes"] and a["why"][0] == "coarse pass"
    assert set(a["why"]) <= {"coarse pass", "covering, lattice", "covering", "resolving a candidate",
                             "measuring a detection's disc", "no sweep reveals more"}
    assert beliefs and beliefs[-1].final and len(beliefs[-1].stiffness) == 9 * 9
    assert np.all(np.isfinite(beliefs[-1].stiffness))
    # the scanner touched off first: its sweeps follow the surface it found (1 mm working offset), not contact_z_mm
    assert probing_z and min(probing_z) < 6.0
    # where an inclusion could still hide, per size: what the stop rule's miss probability averages, and map.npz's
    # grid is the smallest size's (reach_mm 2 here, up to 6.5 mm for the largest radius)
    hiding = a["unsensed"]
    reaches, fractions = [h["reach_mm"] for h in hiding], [h["fraction"] for h in hiding]
    assert reaches[0] == 2.0 and reaches == sorted(reaches) and len(reaches) == 10
    assert fractions == sorted(fractions, reverse=True) and 0.0 < fractions[0] < 1.0
    # the stop rule counts the given-up sweeps' cells as done (nothing more can be done there); the report counts
    # them as unsensed, and map.npz's grid (the smallest size's) is grey at the given-up points
    miss = float(a["stop"].split("miss probability ")[1].split(",")[0])
    assert np.mean(fractions) > miss + 0.01
    grid = np.load(tmp_path / "a" / "map" / "map.npz")
    assert grid["unsensed"].shape == grid["stiffness"].shape
    # beside it, the grids its detection used: the measured cells (values where the map has them) and, of those,
    # the stiffness-blind sweeps' (the coarse pass's), so that the detection can be run again offline
    measured, fair = np.isfinite(grid["measured"]), np.isfinite(grid["fair"])
    assert fair.any() and np.all(measured[fair]) and np.all(np.isfinite(grid["stiffness"])[measured])
    assert np.array_equal(grid["measured"][measured], grid["stiffness"][measured])
    assert grid["unsensed"].mean() == pytest.approx(fractions[0], abs=1e-4)
    far = [(x, y) for x, y in a["given_up"] if x > max(px for px, _ in a["points"]) + 4.0]  # no probe near them
    assert far and all(grid["unsensed"][int(np.argmin(np.abs(grid["y_mm"] - y))), int(np.argmin(np.abs(grid["x_mm"] - x)))]
                       for x, y in far), (a["given_up"], a["points"])
    b, inc_b, _, _ = _adaptive(tmp_path / "b")
    assert a["points"] == b["points"] and inc_a == inc_b


def test_the_planners_knobs_default_alike_in_the_model_the_node_and_the_launch_file() -> None:
    """A default tuned in models.adaptive.PlannerConfig must be the one a launch runs: the node's Params and the
    launch file's args repeat it (a drift between them once evaluated one setting and shipped another)."""
    from dataclasses import fields

    from models.adaptive import PlannerConfig
    from nodes.scanner.adaptive_planner import AdaptivePlanner

    model = PlannerConfig((0.0, 0.0, 40.0, 40.0))
    node = AdaptivePlanner.Params()
    args = load_launch(REPO / "launch" / "scan_adaptive_sim.yaml", {}, run_dir=Path("runs") / "unused").args
    shared = [f.name for f in fields(PlannerConfig) if f.name != "region_mm" and hasattr(node, f.name)]
    assert {"near_miss_false_alarm", "miss_probability", "suspect_false_alarm", "cover_column_mm",
            "interior_gap_mm"} <= set(shared)
    def plain(v: object) -> object:   # a list param or arg for a tuple field
        return tuple(v) if isinstance(v, list) else v

    for name in shared:
        assert plain(getattr(node, name)) == getattr(model, name), name
        if name in args and name != "seed_spacing_mm":   # the air-float launch's own seed: 14 mm, not the 4 x 4 grid
            assert plain(args[name]) == getattr(model, name), name


def scanned(tmp: Path, params: dict[str, Any], stiffness: Callable[[float, float], float]) -> AdaptivePlanner:
    """An AdaptivePlanner of ``params`` (``output_dir``: ``tmp``) run to its end in memory (palpa.testing.GraphHarness)
    against a scanner played here on tissue of ``stiffness`` (x, y in mm): each sweep answered with 25 air-float
    estimates along its line, then, 0.2 s after the answer, 40 of the probe resting at the line's end, measured
    before the answer and arriving after the planner asked for its next probe (as the estimator delivers them)."""
    import palpa
    from messages import ProbeAt, ProbeResult, StiffnessSample
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.node.service import Responder
    from palpa.testing import GraphHarness

    g = GraphHarness()
    planner = g.add(AdaptivePlanner, {**params, "output_dir": str(tmp)}, name="planner")
    scanner = g.add(palpa.Node, name="scanner")
    status = scanner.publisher("robot/scan_status", ScanStatus, latched=True)
    status.publish(ScanStatus(stamp_ns=g.clock.now_ns(), state="idle", line=0, lines=0, progress=0.0, eta_s=0.0))
    samples = scanner.publisher("stiffness/sample", StiffnessSample)

    def sample(x: float, y: float, stamp_ns: int) -> None:
        samples.publish(StiffnessSample(stamp_ns=stamp_ns, model="airfloat", x_mm=x, y_mm=y, z_mm=1.0,
                                        value=stiffness(x, y), unit="kPa", valid=True))

    def answer(req: ProbeAt, responder: Responder[ProbeResult]) -> None:
        responder.reply(ProbeResult(x_mm=req.x_mm, y_mm=req.y_mm, value=stiffness(req.x_mm, req.y_mm), unit="kPa",
                                    samples=25, mad=0.0, duration_s=1.0))
        # measured resting at the line's end until now, delivered by the estimator 0.2 s later (the planner has
        # asked for its next probe by then)
        now = g.clock.now_ns()
        scanner.timer(0.2, lambda: [sample(req.x_mm, req.y_mm + 3.0, now - 10_000_000 * i) for i in range(40)],
                      oneshot=True)

    def probe_at(req: ProbeAt) -> Responder[ProbeResult]:
        for i in range(25):
            sample(req.x_mm, req.y_mm - 3.0 + 0.25 * i, g.clock.now_ns())
        responder = srv.defer()
        scanner.timer(0.5, lambda: answer(req, responder), oneshot=True)
        return responder

    srv = scanner.service("scanner/probe_at", ProbeAt, ProbeResult, probe_at)
    for _ in range(4000):
        if planner.done:
            break
        g.advance(0.05)
    assert planner.done
    g.advance(0.5)   # its map written, its exit asked for
    g.close()
    return planner


def test_a_probes_late_estimates_count_as_that_probes_not_the_next_ones(tmp_path: Path) -> None:
    """The scanner answers a while after a path ends, the probe resting on the tissue meanwhile: estimates of that
    probe arrive after its answer and after the next request. They belong to the probe that measured them: a
    resolving sweep's stiff end in the stiffness-blind baseline (when a covering sweep followed) raised the
    detector's threshold and lost a weak inclusion. Here a scanner played by the test (:func:`scanned`) answers each
    sweep with its line's estimates, then publishes the resting probe's estimates at the sweep's end; the tissue is
    stiff around one point, so the planner resolves it, then covers the rest blind."""
    def stiffness(x: float, y: float) -> float:
        return 10.0 + 8.0 * float(np.exp(-((x - 15.0) ** 2 + (y - 16.0) ** 2) / 8.0))

    planner = scanned(tmp_path, {"region_mm": [0.0, 0.0, 30.0, 30.0], "seed_spacing_mm": 14.0, "max_probes": 30,
                                 "coarse_pass": False}, stiffness)   # blind and resolving sweeps mixed
    blind = planner.blind
    assert any(not a and b for a, b in zip(blind, blind[1:], strict=False))   # a blind sweep after a resolving one
    assert any(a and not b for a, b in zip(blind, blind[1:], strict=False))   # and the other way round
    # every cell of the baseline's grid lies on a blind probe's line, and every blind line's end is in it
    fair = planner.fair.snapshot()
    gx, gy = np.meshgrid(fair.x_mm, fair.y_mm)
    on_blind = np.zeros(gx.shape, dtype=bool)
    for (px, py), b in zip(planner.probed, blind, strict=True):
        if b:
            on_blind |= (np.abs(gx - px) <= 1.0) & (np.abs(gy - py) <= 4.0)
    assert np.all(on_blind[np.isfinite(fair.stiffness)])
    ends = [(px, py + 3.0) for (px, py), b in zip(planner.probed[:-1], blind, strict=False) if b]
    for x, y in ends:
        i, j = int(np.argmin(np.abs(fair.y_mm - y))), int(np.argmin(np.abs(fair.x_mm - x)))
        assert np.isfinite(fair.stiffness[i, j]), (x, y)


def test_a_map_that_cannot_be_written_ends_the_planner_non_zero_saying_why(tmp_path: Path,
                                                                         caplog: pytest.LogCaptureFixture) -> None:
    """A full disk at the end of a scan (a bench set filled it: OSError 28 in map.npz) left the planner done and
    silent, and the launch waited on it until it was killed. Its output folder here lies under a file, so nothing
    can be written: the planner says where and why and asks to end with exit code 1; where it can write, 0."""
    def stiffness(x: float, y: float) -> float:
        return 10.0

    params = {"region_mm": [0.0, 0.0, 20.0, 20.0], "seed_spacing_mm": 14.0, "max_probes": 8, "coarse_pass": False}
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with caplog.at_level(logging.ERROR):
        planner = scanned(blocker / "map", params, stiffness)
    assert planner.exit_code == 1
    assert any("the map could not be written to" in r.getMessage() and str(blocker / "map") in r.getMessage()
               for r in caplog.records)
    assert scanned(tmp_path / "map", params, stiffness).exit_code == 0
    assert (tmp_path / "map" / "map.npz").exists()


def test_where_two_probes_lines_overlap_a_sample_is_the_one_measuring_at_its_stamp(tmp_path: Path) -> None:
    """An estimate on both the last sweep's line and the one in flight is the one in flight's only when measured
    after it was asked for (the resting probe's estimates of the last sweep arrive late)."""
    from messages import StiffnessSample
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import NodeHarness

    h = NodeHarness(AdaptivePlanner, {"region_mm": [0.0, 0.0, 30.0, 30.0], "output_dir": str(tmp_path)})
    p, now = h.node.samples, h.clock.now_ns()   # as the planner made it from its parameters (6 mm sweeps)
    p.sent((10.0, 10.0), False, now - 10)
    p.answered((0, 0))
    p.sent((10.0, 12.0), True, now)

    def at(stamp_ns: int, y: float = 13.0) -> StiffnessSample:
        return StiffnessSample(stamp_ns=stamp_ns, model="airfloat", x_mm=10.0, y_mm=y, z_mm=1.0, value=12.0,
                               unit="kPa", valid=True)

    assert p.measured_by(at(now - 1)) is False and p.measured_by(at(now)) is True
    assert p.measured_by(at(now - 1, y=16.0)) is None     # on the sweep in flight only, measured before it
    assert p.measured_by(at(now, y=16.0)) is True and p.measured_by(at(now, y=20.0)) is None
    h.close()


def test_estimates_lost_on_the_way_or_none_at_all_make_the_planners_run_incomplete(tmp_path: Path) -> None:
    """The planner bins the estimator's estimates itself: two of them lost on the way (a gap in the publisher's
    sequence), or none reaching it at all, and its run cannot end clean, whatever it probed."""
    import msgspec

    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import NodeHarness
    from tests.test_map_aggregator import sample

    def raw(seq: int) -> list[bytes]:  # the estimator's seq-th estimate, along the probe's sweep
        header = msgspec.msgpack.encode({"type": "StiffnessSample", "seq": seq, "stamp": 1, "node": "estimator",
                                         "inc": 7})
        return [b"stiffness/sample", header, msgspec.msgpack.encode(sample(5.0, 2.0 + 0.6 * seq, 26.0))]

    for lost, out in (((), "ok"), ((6, 7), "lost"), (tuple(range(1, 11)), "none")):
        h = NodeHarness(AdaptivePlanner, {"output_dir": str(tmp_path / out), "region_mm": [0.0, 0.0, 20.0, 20.0]})
        h.node.probed, h.node.blind = [(5.0, 5.0)], [True]   # as after its first probe, a sweep along y at x = 5
        h.node.samples.sent((5.0, 5.0), True, 0)
        h.node.samples.answered((0, 0))
        for seq in (s for s in range(1, 11) if s not in lost):
            h.publish_raw(raw(seq))
        if len(lost) < 10:
            h.node._update_belief()
        h.node.finish("the test ends it")
        h.advance(0.5)
        report = json.loads((tmp_path / out / "planner.json").read_text())
        assert h.node.exit_code == (1 if lost else 0), report
        assert report["incomplete"] == {
            "ok": "", "lost": "stiffness/sample lost 2 message(s) and its publisher restarted 0 time(s)",
            "none": "no valid stiffness estimate reached the planner: there is no map"}[out]
        h.close()


def test_the_planner_keeps_only_what_a_probe_measured_on_its_measuring_part(tmp_path: Path) -> None:
    """The scanner's answer says when the probe measured; the transit over the line at the retract height (before)
    and the retract (after) are heard on the line too, and left out of the planner's map, as out of the answer."""
    from messages import ProbeResult, StiffnessSample
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import NodeHarness

    h = NodeHarness(AdaptivePlanner, {"region_mm": [0.0, 0.0, 30.0, 30.0], "output_dir": str(tmp_path)})
    p, now = h.node, h.clock.now_ns()
    p.samples.sent((10.0, 12.0), True, now)

    def at(stamp_ns: int, value: float) -> StiffnessSample:
        return StiffnessSample(stamp_ns=stamp_ns, model="airfloat", x_mm=10.0, y_mm=12.0, z_mm=1.0, value=value,
                               unit="kPa", valid=True)

    for i, value in ((1, 99.0), (2, 12.0), (3, 12.0), (4, 99.0)):   # transit, two on the line, retract
        p.on_sample(at(now + i * 1_000_000, value))
    assert p.samples.take() == []   # nothing binned before the answer says when

    class Answered:
        def exception(self) -> None:
            return None

        def result(self) -> ProbeResult:
            return ProbeResult(x_mm=10.0, y_mm=12.0, value=12.0, unit="kPa", samples=2, mad=0.0, duration_s=1.0,
                               measured_from_ns=now + 2_000_000, measured_to_ns=now + 3_000_000)

    p._update_belief = lambda: None   # type: ignore[method-assign]   # the binning, not the GP, is under test
    p.on_result(Answered())   # type: ignore[arg-type]
    assert [v for _, _, v, _ in p.samples.take()] == [12.0, 12.0]
    p.on_sample(at(now + 5_000_000, 99.0))   # the last probe's, arriving late but measured after its span
    p.on_sample(at(now + 2_500_000, 12.0))   # ... and one measured inside it
    assert [v for _, _, v, _ in p.samples.take()] == [12.0]
    h.close()
