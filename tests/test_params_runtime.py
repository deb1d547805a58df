"""Runtime parameters on the in-memory bus: get, set with validation naming the field, the node's hook refusing
or applying a change, changes published on _palpa/params; only parameters declared run-time changeable change,
safety limits never do."""

from __future__ import annotations

import pytest

import palpa
from nodes.demo import Talker
from palpa.node.params import change_rules
from palpa.node.params_runtime import PARAMS_TOPIC, ParamGet, ParamSet, ParamValues, param_service
from palpa.node.service import BadRequestError, RequestRefused
from palpa.testing import GraphHarness


class Tuned(palpa.Node):
    class Params(palpa.Params):
        gain: palpa.RunTime[float] = 1.0
        mode: palpa.RunTime[str] = "a"
        limits: palpa.RunTime[tuple[float, float]] = (0.0, 1.0)
        fixed: float = 0.0
        """Not declared run-time changeable: fixed at launch."""
        cap: palpa.SafetyLimit[palpa.Positive] = 5.0

    def setup(self) -> None:
        self.seen: list[tuple[float, float]] = []

    def on_params_changed(self, old: Tuned.Params, new: Tuned.Params) -> bool | None:
        if new.mode == "locked":
            return False
        if new.gain > 10:
            raise palpa.ParamError(f"parameter 'gain': {new.gain} is over 10")
        self.seen.append((old.gain, new.gain))
        return None


def setup_graph(cls: type[palpa.Node] = Tuned, name: str = "tuned") -> tuple[GraphHarness, palpa.Node, palpa.Node]:
    g = GraphHarness()
    node = g.add(cls, name=name, serve_params=True)
    return g, node, g.add(palpa.Node, name="operator")


def call(g: GraphHarness, op: palpa.Node, verb: str, req: ParamGet | ParamSet, node: str = "tuned") -> ParamValues:
    fut = op.client(param_service(node, verb), type(req), ParamValues).call_async(req)
    g.spin()
    return fut.result()


def test_get_and_set_apply_at_once_and_publish_the_change() -> None:
    g, node, op = setup_graph()
    got = call(g, op, "get", ParamGet())
    assert got.values == {"gain": 1.0, "mode": "a", "limits": [0.0, 1.0], "fixed": 0.0, "cap": 5.0}
    assert got.types["gain"] == "float = 1.0" and got.types["cap"] == "float = 5.0"
    assert got.change == {"gain": "run time", "mode": "run time", "limits": "run time", "fixed": "launch",
                          "cap": "safety limit"}
    after = call(g, op, "set", ParamSet(values={"gain": 2, "limits": [0.5, 2.0]}))
    assert after.values["gain"] == 2.0 and node.params.gain == 2.0 and node.params.limits == (0.5, 2.0)
    assert isinstance(node, Tuned) and node.seen == [(1.0, 2.0)]
    changes = g.published(PARAMS_TOPIC)
    assert len(changes) == 1 and changes[0].changed == {"gain": 2.0, "limits": [0.5, 2.0]}
    assert changes[0].previous == {"gain": 1.0, "limits": [0.0, 1.0]}
    call(g, op, "set", ParamSet(values={"gain": 2.0}))  # no change: the hook is not called, nothing published
    assert len(g.published(PARAMS_TOPIC)) == 1 and node.seen == [(1.0, 2.0)]


def test_invalid_unknown_and_refused_changes_leave_the_params_alone() -> None:
    g, node, op = setup_graph()
    with pytest.raises(BadRequestError, match="parameter 'gain': Expected `float`, got `str`"):
        call(g, op, "set", ParamSet(values={"gain": "fast"}))
    with pytest.raises(BadRequestError, match=r"parameter 'limits\[1\]'"):
        call(g, op, "set", ParamSet(values={"limits": [0.0, "x"]}))
    with pytest.raises(BadRequestError, match="no parameter 'gian'"):
        call(g, op, "set", ParamSet(values={"gian": 2.0}))
    with pytest.raises(RequestRefused, match="refused the change of gain, mode"):
        call(g, op, "set", ParamSet(values={"mode": "locked", "gain": 3.0}))
    with pytest.raises(RequestRefused, match="over 10"):
        call(g, op, "set", ParamSet(values={"gain": 11.0}))
    assert node.params == Tuned.Params()
    assert g.published(PARAMS_TOPIC) == []


def test_talker_retimes_on_a_new_rate() -> None:
    g, node, op = setup_graph(Talker, "talker")
    g.advance(1.0)
    before = len(g.published("chatter"))
    call(g, op, "set", ParamSet(values={"rate_hz": 20}), node="talker")
    g.advance(1.0)
    assert len(g.published("chatter")) - before in (20, 21)
    # the bound is in the Params type (palpa.Positive): refused as a bad request before the node sees it
    with pytest.raises(BadRequestError, match=r"'rate_hz': Expected `float` > 0.0"):
        call(g, op, "set", ParamSet(values={"rate_hz": 0}), node="talker")


def test_a_parameter_not_declared_run_time_is_refused_and_a_safety_limit_says_so() -> None:
    g, node, op = setup_graph()
    with pytest.raises(RequestRefused, match=r"parameter 'fixed' is fixed at launch \(the node does not apply a "
                                             r"change while it runs; it may change: gain, mode, limits\)"):
        call(g, op, "set", ParamSet(values={"fixed": 1.0}))
    with pytest.raises(RequestRefused, match="parameter 'cap' is a safety limit, fixed at launch: change it in the "
                                             "launch file"):
        call(g, op, "set", ParamSet(values={"cap": 50.0}))
    # with a run-time one beside it: the whole set is refused, the limit named first
    with pytest.raises(RequestRefused, match="parameter 'cap' is a safety limit"):
        call(g, op, "set", ParamSet(values={"gain": 2.0, "fixed": 1.0, "cap": 50.0}))
    assert node.params == Tuned.Params() and isinstance(node, Tuned) and node.seen == []
    assert g.published(PARAMS_TOPIC) == []
    # the value it has is no change: accepted (what `param load` of a `param dump` sends)
    assert call(g, op, "set", ParamSet(values={"cap": 5, "fixed": 0.0, "gain": 3.0})).values["gain"] == 3.0


def test_the_default_is_fixed_at_launch_and_a_limit_cannot_be_run_time() -> None:
    class Plain(palpa.Params):
        rate_hz: palpa.Positive = 1.0
        name: str = ""

    assert change_rules(Plain) == {"rate_hz": "launch", "name": "launch"}

    class Both(palpa.Params):
        box: palpa.RunTime[palpa.SafetyLimit[float]] = 1.0

    with pytest.raises(TypeError, match="'box' is declared both RunTime and SafetyLimit"):
        change_rules(Both)


def test_the_shipped_safety_limits_are_declared_so() -> None:
    """Every shipped node's declaration reads (no parameter both), and the robot's and the pressure's limits are
    safety limits; no scan node declares anything run-time changeable (none applies a change while it runs)."""
    import importlib
    import pkgutil

    import nodes
    from nodes.probe.pressure_controller import PressureController
    from nodes.scanner.robot_scanner import RobotScanner

    classes = [c for m in pkgutil.walk_packages(nodes.__path__, "nodes.")
               for c in vars(importlib.import_module(m.name)).values()
               if isinstance(c, type) and issubclass(c, palpa.Node) and c is not palpa.Node]
    rules = {f"{c.__name__}.{k}": v for c in classes for k, v in change_rules(c.Params).items()}
    assert {k for k, v in rules.items() if v == "run time"} == {"Talker.rate_hz", "Talker.text", "Talker.count"}
    scanner, pressure = change_rules(RobotScanner.Params), change_rules(PressureController.Params)
    for name in ("workspace_mm", "max_speed_mm_s", "max_accel_mm_s2", "watchdog_s", "pressure_watchdog_s",
                 "watch_topic", "rtde_watchdog_hz", "follow_max_offset_mm", "max_press_fraction"):
        assert scanner[name] == "safety limit", name
    for name in ("max_kpa", "tracking_tolerance_kpa", "tracking_timeout_s", "lost_timeout_s"):
        assert pressure[name] == "safety limit", name
