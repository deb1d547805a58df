"""Runtime parameters on the in-memory bus: get, set with validation naming the field, the node's hook refusing
or applying a change, changes published on _palpa/params."""

from __future__ import annotations

import pytest

import palpa
from nodes.demo import Talker
from palpa.node.params_runtime import PARAMS_TOPIC, ParamGet, ParamSet, ParamValues, param_service
from palpa.node.service import BadRequestError, RequestRefused
from palpa.testing import GraphHarness


class Tuned(palpa.Node):
    class Params(palpa.Params):
        gain: float = 1.0
        mode: str = "a"
        limits: tuple[float, float] = (0.0, 1.0)

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
    assert got.values == {"gain": 1.0, "mode": "a", "limits": [0.0, 1.0]}
    assert got.types["gain"] == "float = 1.0"
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
