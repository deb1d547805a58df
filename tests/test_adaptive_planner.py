"""The adaptive planner node driving the real scanner, composed in memory (launch/scan_adaptive_sim.yaml, small)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from messages import RobotPose, ScanStatus, StiffnessMap
from palpa.clock import MockClock
from palpa.compose import Composition
from palpa.launch import load_launch, parse_overrides
from palpa.launch.compose import compose_plan
from palpa.node import Node
from tests.procs import REPO

# contact_z_mm is the flat height a probe would sweep at without a touch-off: far above the dome (3-4 mm thick here)
# reach_mm: 2 so that the detection rule has more than two sweeps' worth of tissue to cover in this small region
SMALL = ["region_mm:=[36.0, 33.0, 54.0, 51.0]", "initial:=2", "seed_spacing_mm:=0", "max_probes:=8", "contact_z_mm:=8.0",
         "reach_mm:=2.0",
         f"geometry:={REPO / 'phantoms' / 'measured' / 'airfloat_tumours.yaml'}"]
BOX_X_MAX = 46.0
"""The scanner's workspace ends here in these tests: the planner's points at x = 49.5 mm lie outside it."""


def _adaptive(tmp: Path) -> tuple[dict[str, Any], list[dict[str, float]], list[StiffnessMap], list[float]]:
    from palpa.cli.run import load_node_class

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
    assert comp.run(max_sim_s=300.0) == 0
    out = tmp / "map"
    assert (out / "map.npz").exists()
    return (json.loads((out / "planner.json").read_text()), json.loads((out / "inclusions.json").read_text()),
            beliefs, probing_z)


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
    # every probe says why it was made: the seed grid first, then what the acquisition chose it for
    assert len(a["why"]) == a["probes"] and a["why"][0] == "seed"
    assert set(a["why"]) <= {"seed", "covering, lattice", "covering", "resolving a candidate",
                             "measuring a detection's disc", "no sweep reveals more"}
    assert beliefs and beliefs[-1].final and len(beliefs[-1].stiffness) == 9 * 9
    assert np.all(np.isfinite(beliefs[-1].stiffness))
    # the scanner touched off first: its sweeps follow the surface it found (1 mm working offset), not contact_z_mm
    assert probing_z and min(probing_z) < 6.0
    b, inc_b, _, _ = _adaptive(tmp_path / "b")
    assert a["points"] == b["points"] and inc_a == inc_b


def test_the_planners_knobs_default_alike_in_the_model_the_node_and_the_launch_file() -> None:
    """A default tuned in models.adaptive.PlannerConfig must be the one a launch runs: the node's Params and the
    launch file's args repeat it (a drift between them once evaluated one setting and shipped another)."""
    from dataclasses import fields

    from models.adaptive import PlannerConfig
    from nodes.adaptive_planner import AdaptivePlanner

    model = PlannerConfig((0.0, 0.0, 40.0, 40.0))
    node = AdaptivePlanner.Params()
    args = load_launch(REPO / "launch" / "scan_adaptive_sim.yaml", {}, run_dir=Path("runs") / "unused").args
    shared = [f.name for f in fields(PlannerConfig) if f.name != "region_mm" and hasattr(node, f.name)]
    assert {"near_miss", "miss_probability", "suspect", "cover_column_mm", "interior_gap_mm"} <= set(shared)
    for name in shared:
        assert getattr(node, name) == getattr(model, name), name
        if name in args and name != "seed_spacing_mm":   # the air-float launch's own seed: 14 mm, not the 4 x 4 grid
            assert args[name] == getattr(model, name), name
