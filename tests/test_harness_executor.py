"""The test harness is a facade over the one in-process executor, :class:`palpa.timing.compose.Composition`
(issue 38): the same event order as ``palpa launch --in-process``, and launch files composed in the test process.
The harness against a real ``--in-process`` launch: tests/test_executor_timeline.py (system tier)."""

from __future__ import annotations

from pathlib import Path

import pytest

from messages import Text
from palpa.errors import LaunchError
from palpa.launch import parse_overrides
from palpa.node.node import Node
from palpa.testing import GraphHarness
from tests.test_compose import SMALL
from tests.test_launch_smoke import REPO


class _Early(Node):
    """Publishes on ``chatter`` from a timer every 0.1 s."""

    def setup(self) -> None:
        self.out = self.publisher("chatter", Text)
        self.timer(0.1, lambda: self.out.publish(Text(text="tick", stamp_ns=self.clock.now_ns())))


class _Late(Node):
    """Notes, at each of its 0.1 s ticks, the stamps of the ``chatter`` it has heard so far."""

    def setup(self) -> None:
        self.heard: list[int] = []
        self.seen_at_tick: list[list[int]] = []
        self.subscribe("chatter", Text, lambda m: self.heard.append(m.stamp_ns))
        self.timer(0.1, lambda: self.seen_at_tick.append(list(self.heard)))


@pytest.mark.parametrize("order", ["early first", "late first"])
def test_every_timer_of_an_instant_runs_before_its_messages_whatever_the_order_of_nodes(order: str) -> None:
    """At 0.1 s both timers are due: the late node's tick has not yet heard the message sent at that instant
    (as in a composition), and hears it right after, before time moves on."""
    nodes: list[tuple[type[Node], None]] = [(_Early, None), (_Late, None)]
    with GraphHarness(nodes if order == "early first" else nodes[::-1]) as g:
        start = g.clock.now_ns()
        late = next(n for n in g.nodes if isinstance(n, _Late))
        g.advance(0.25)
        assert late.seen_at_tick == [[], [start + 100_000_000]]
        assert late.heard == [start + 100_000_000, start + 200_000_000]


def test_spin_runs_the_timers_due_now_then_the_messages() -> None:
    """Time set by hand onto a deadline: spin runs it like a step of the composition, without moving time."""
    with GraphHarness([(_Early, None), (_Late, None)]) as g:
        late = next(n for n in g.nodes if isinstance(n, _Late))
        g.clock.advance(0.1)
        g.spin()
        assert late.seen_at_tick == [[]]
        assert late.heard == [g.clock.now_ns()]


def test_from_launch_composes_the_files_sim_clock_nodes_with_the_args(tmp_path: Path) -> None:
    """The scan graph in the test process: its simulated-clock nodes in the file's order (not its clock source),
    each with the file's parameters, the args and the node parameters given, and they run: the arm moves, the
    probe reads (no process: the map's PNG helper is turned off)."""
    args = parse_overrides([*SMALL, "pressure_kpa:=33.0"])
    with GraphHarness.from_launch(REPO / "launch" / "scan_sim.yaml", run_dir=tmp_path,
                                  node_params={"map": {"png_helper": False}}, **args) as g:
        assert [n.name for n in g.nodes] == ["pressure", "fibre", "estimator", "map", "scanner"]
        pressure = g.nodes[0]
        assert pressure.params.setpoint_kpa == 33.0  # type: ignore[attr-defined]
        assert g.nodes[3].params.png_helper is False  # type: ignore[attr-defined]
        scanner = g.nodes[4]
        assert list(scanner.params.region_mm) == [30.0, 6.0, 54.0, 30.0]  # type: ignore[attr-defined]
        g.advance(2.0)
        assert len(g.published("robot/pose")) >= 100
        assert g.published("probe/heights")


def test_from_launch_says_what_is_wrong_with_an_arg(tmp_path: Path) -> None:
    with pytest.raises(LaunchError, match="no_such_arg"):
        GraphHarness.from_launch(REPO / "launch" / "scan_sim.yaml", run_dir=tmp_path, no_such_arg=1)


def test_from_launch_refuses_a_file_without_sim_clock_nodes(tmp_path: Path) -> None:
    with pytest.raises(LaunchError, match="no node runs on the simulated clock"):
        GraphHarness.from_launch(REPO / "launch" / "talker_listener.yaml", run_dir=tmp_path)


def test_from_launch_refuses_node_params_for_a_node_it_does_not_compose(tmp_path: Path) -> None:
    with pytest.raises(LaunchError, match="node_params for clock: no such simulated-clock node"):
        GraphHarness.from_launch(REPO / "launch" / "scan_sim.yaml", run_dir=tmp_path, node_params={"clock": {}})


def test_a_composition_with_a_bridge_refuses_a_bus_of_the_callers() -> None:
    """Its bridge forwards what its own bus carries: a bus given by the caller would not go out."""
    from palpa.net.memory import MemoryBus
    from palpa.timing.compose import Composition
    from tests.test_compose import _LateEchoBus

    with pytest.raises(ValueError, match="runs on its own bus"):
        Composition(bridge=_LateEchoBus(), bus=MemoryBus())  # type: ignore[arg-type]
