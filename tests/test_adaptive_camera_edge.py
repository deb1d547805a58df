"""The camera planner's presses at the specimen's edge (models.adaptive_edge, nodes.scanner.adaptive_planner): it
presses only where every tip of the probe lands on the measured footprint, and a press the scanner cannot answer
does not hold LSE's stop rule nor bring the next press beside it (BENCHMARKS.md, "Camera probe")."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from models.adaptive_edge import press_region, probe_tips


def test_the_camera_probes_tips_reach_8_mm_up_and_7_8_mm_sideways_but_not_down() -> None:
    """The paper's layout (models.multi_indenter.ProbeGeometry.paper): what makes three edges of the usual region
    unanswerable and the fourth (y0) answerable, as the raster's recording shows (37 of its 169 presses)."""
    tips = probe_tips(8.0)
    xs, ys = [t[0] for t in tips], [t[1] for t in tips]
    assert (0.0, 0.0) in tips and len(tips) == 4
    assert max(ys) == pytest.approx(8.0) and min(ys) == pytest.approx(-1.663, abs=1e-3)
    assert max(xs) == pytest.approx(7.825, abs=1e-3) and min(xs) == pytest.approx(-7.825, abs=1e-3)


def test_the_press_region_keeps_every_tip_a_margin_inside_the_footprint() -> None:
    region = (7.0, 7.0, 53.0, 53.0)        # the bench's: 7 mm inside a 60 mm specimen's true edges
    footprint = (0.0, 0.0, 60.0, 60.0)
    tips = probe_tips(8.0)
    x0, y0, x1, y1 = press_region(region, footprint, tips, 1.0)
    assert (x0, x1) == pytest.approx((8.825, 51.175), abs=1e-3)   # 7.8 mm of tip + 1 mm inside each x edge
    assert y1 == pytest.approx(51.0)                               # 8 mm of tip + 1 mm below the top edge
    assert y0 == 7.0                                               # the tips reach 1.7 mm down: the region binds
    for px, py in ((x0, y0), (x0, y1), (x1, y0), (x1, y1)):        # every corner press: every tip on the specimen
        for tx, ty in tips:
            assert 1.0 - 1e-9 <= px + tx <= 59.0 + 1e-9 and 1.0 - 1e-9 <= py + ty <= 59.0 + 1e-9
    # the uncut region's edges put a tip off the specimen (the raster's presses there: no valid estimate)
    assert region[0] + min(t[0] for t in tips) < 0.0 and region[3] + max(t[1] for t in tips) > 60.0
    assert press_region(region, footprint, [], 1.0) == region            # no tips (the air-float probe): as given
    assert press_region((20.0, 20.0, 30.0, 30.0), footprint, tips, 1.0) == (20.0, 20.0, 30.0, 30.0)
    with pytest.raises(ValueError, match="keeps every tip"):
        press_region(region, (0.0, 0.0, 15.0, 60.0), tips, 1.0)


def _geometry(tmp: Path, footprint: list[float]) -> Path:
    path = tmp / "geometry.yaml"
    path.write_text(yaml.safe_dump({"thickness_mm": 10.0, "error_mm": 0.2, "footprint_mm": footprint}))
    return path


def test_the_camera_planner_presses_only_where_its_tips_land_on_the_footprint(tmp_path: Path) -> None:
    """The node cuts the region it is given (as the bench gives it) to the press region, with tip_circle_mm, in
    indent mode; the sweeping air-float planner and tip_circle_mm 0 keep it."""
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import NodeHarness

    geometry = str(_geometry(tmp_path, [0.0, 0.0, 59.0, 47.5]))   # generated phantom 0's measured footprint
    common = {"region_mm": [7.0, 7.0, 52.1, 41.1], "geometry": geometry, "output_dir": str(tmp_path / "out"),
              "resolution_mm": 4.0}
    cases = (({"mode": "indent", "tip_circle_mm": 8.0}, (8.825, 7.0, 50.175, 38.5)),
             ({"mode": "indent", "tip_circle_mm": 0.0}, (7.0, 7.0, 52.1, 41.1)),
             ({"mode": "sweep", "tip_circle_mm": 8.0}, (7.0, 7.0, 52.1, 41.1)))
    for extra, want in cases:
        h = NodeHarness(AdaptivePlanner, {**common, **extra})
        assert h.node.cfg.region_mm == pytest.approx(want, abs=1e-3), extra
        h.close()
    # without region_mm: the footprint less edge_margin_mm (6 mm), then cut as well
    h = NodeHarness(AdaptivePlanner, {"geometry": geometry, "mode": "indent", "tip_circle_mm": 8.0,
                                      "output_dir": str(tmp_path / "out2"), "resolution_mm": 4.0})
    assert h.node.cfg.region_mm == pytest.approx((8.825, 6.0, 50.175, 38.5), abs=1e-3)
    h.close()


def test_the_camera_launch_files_give_the_planner_the_probes_tips() -> None:
    from palpa.launch import load_launch
    from tests.procs import REPO

    for name in ("scan_adaptive_camera_sim.yaml", "scan_adaptive_camera_ur.yaml"):
        launch = load_launch(REPO / "launch" / name, {}, run_dir=Path("runs") / "unused")
        assert launch.args["tip_circle_mm"] == 8.0, name
        planner = next(n for n in launch.nodes if n.name == "planner")
        assert planner.params["tip_circle_mm"] == 8.0, name



def test_lse_cells_of_a_press_given_up_do_not_hold_the_stop(tmp_path: Path) -> None:
    """The edge rule (as the detect rule's, models.adaptive_detect.swept_cells): the cells of a point given up count
    as resolved. Without it LSE counts an edge the probe cannot answer from as ambiguous for ever (its cells never
    measured, their spread the prior's) and spends its budget on it (BENCHMARKS.md, "Camera probe")."""
    import numpy as np

    from models.adaptive import Belief
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import NodeHarness

    h = NodeHarness(AdaptivePlanner, {"region_mm": [0.0, 0.0, 24.0, 24.0], "mode": "indent", "stop_rule": "lse",
                                      "resolution_mm": 4.0, "initial": 3, "max_probes": 60, "stop_area_mm2": 64.0,
                                      "output_dir": str(tmp_path)})
    p = h.node
    xs = ys = np.arange(2.0, 24.0, 4.0)
    inner = [(float(x), float(y)) for y in ys for x in xs if x < 22.0]
    edge = [(22.0, float(y)) for y in ys]                           # the last column: a tip off the specimen
    p.grid.add([x for x, _ in inner], [y for _, y in inner], [26.0] * len(inner))
    p.probed, p.blind, p.why = list(inner), [True] * len(inner), ["seed"] * len(inner)
    mean = np.full((6, 6), 26.0)
    std = np.where(np.arange(6)[None, :] == 5, 10.0, 0.1) * np.ones((6, 1))   # the edge column: the prior's spread
    p.belief = Belief(x_mm=xs, y_mm=ys, mean=mean, std=std, baseline=26.0, level=31.2)
    stop, why = p._decide()
    assert not stop and p.queue[-1][0][0] == 22.0, why              # the edge is asked for ...
    p.queue.clear()
    p.given_up = list(edge)                                         # ... and cannot be answered
    stop, why = p._decide()
    assert stop and why.startswith("map classified"), why
    h.close()


def test_the_camera_sim_launch_plans_on_the_detection_rule_with_the_presses_reach() -> None:
    """BENCHMARKS.md, "Camera probe": the detection rule with a 3 mm reach found 16 of 16 (the raster 13) where LSE
    found 9-10 of 11 on its budget; the air-float sweeps' 4 mm reach missed 2."""
    from palpa.launch import load_launch
    from tests.procs import REPO

    launch = load_launch(REPO / "launch" / "scan_adaptive_camera_sim.yaml", {}, run_dir=Path("runs") / "unused")
    planner = next(n for n in launch.nodes if n.name == "planner")
    assert planner.params["stop_rule"] == "detect" and planner.params["reach_mm"] == 3.0


def test_the_detection_rule_plans_presses_and_stops_by_itself(tmp_path: Path) -> None:
    """Presses (no sweep, so no covering lattice nor coarse pass) on the detection rule: a seed grid, covering and
    resolving presses, then the stop on detection, before the budget, with the inclusion found where it is. The
    scanner is played by the test: each press answered with the tissue's value at the point."""
    import json
    import math

    import palpa
    from messages import ProbeAt, ProbeResult, ScanStatus, StiffnessSample
    from nodes.scanner.adaptive_planner import AdaptivePlanner
    from palpa.testing import GraphHarness

    g = GraphHarness()
    planner = g.add(AdaptivePlanner, {"region_mm": [0.0, 0.0, 32.0, 32.0], "mode": "indent", "stop_rule": "detect",
                                      "resolution_mm": 4.0, "radius_mm": 2.0, "seed_spacing_mm": 16.0,
                                      "reach_mm": 3.0, "max_probes": 60, "output_dir": str(tmp_path)}, name="planner")
    scanner = g.add(palpa.Node, name="scanner")
    status = scanner.publisher("robot/scan_status", ScanStatus, latched=True)
    status.publish(ScanStatus(stamp_ns=g.clock.now_ns(), state="idle", line=0, lines=0, progress=0.0, eta_s=0.0))
    samples = scanner.publisher("stiffness/sample", StiffnessSample)
    asked: list[tuple[float, float]] = []

    def probe_at(req: ProbeAt) -> ProbeResult:
        asked.append((req.x_mm, req.y_mm))
        d2 = (req.x_mm - 13.0) ** 2 + (req.y_mm - 19.0) ** 2
        value = 0.15 * (1.0 + 2.0 * math.exp(-d2 / 20.0)) * (1.0 + 0.01 * math.sin(7.0 * len(asked)))
        for _ in range(5):
            samples.publish(StiffnessSample(stamp_ns=g.clock.now_ns(), model="multi_indenter", x_mm=req.x_mm,
                                            y_mm=req.y_mm, z_mm=4.0, value=value, unit="N/mm", valid=True))
        return ProbeResult(x_mm=req.x_mm, y_mm=req.y_mm, value=value, unit="N/mm", samples=5, mad=0.0,
                           duration_s=1.0)

    scanner.service("scanner/probe_at", ProbeAt, ProbeResult, probe_at)
    for _ in range(8000):
        if planner.done:
            break
        g.advance(0.05)
    assert planner.done
    g.close()
    report = json.loads((tmp_path / "planner.json").read_text())
    assert report["stop"].startswith("found:"), report["stop"]
    assert report["probes"] < 60 and report["refused"] == 0
    assert "resolving a candidate" in report["why"] and "covering" in report["why"]
    found = json.loads((tmp_path / "inclusions.json").read_text())
    assert len(found) == 1 and math.dist((found[0]["x_mm"], found[0]["y_mm"]), (13.0, 19.0)) < 3.0, found
