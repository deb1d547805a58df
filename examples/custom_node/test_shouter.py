"""Tests of the example node: an in-memory bus and a mock clock, no sockets, no processes (milliseconds)."""

from __future__ import annotations

import pytest
from shouter import Shouter

import palpa
from messages import Text, Trigger, TriggerResult
from palpa.testing import NodeHarness


def test_shouts_what_it_hears() -> None:
    with NodeHarness(Shouter, {"suffix": "!!"}) as h:
        h.publish("chatter", Text(text="hello", stamp_ns=42))
        shouted = h.published("shout")
    assert shouted == [Text(text="HELLO!!", stamp_ns=42)]


def test_every_nth_line() -> None:
    with NodeHarness(Shouter, {"every": 3}) as h:
        for i in range(7):
            h.publish("chatter", Text(text=f"line {i}"))
        assert [m.text for m in h.published("shout")] == ["LINE 2!", "LINE 5!"]


def test_calling_its_service_from_the_test() -> None:
    with NodeHarness(Shouter, {"every": 2}) as h:
        h.publish("chatter", Text(text="one"))
        caller = h.add(palpa.Node, name="caller")  # a second node on the harness's bus makes the call
        reset = caller.client("shouter/reset", Trigger, TriggerResult)
        done = reset.call_async(Trigger())
        h.spin()  # delivers the request, runs the handler, delivers the reply
        assert done.result() == TriggerResult(message="reset after 1 lines", state="ok")
        h.publish("chatter", Text(text="two"))  # counting starts again: the 2nd line after the reset shouts
        assert h.published("shout") == []


def test_remap_and_namespace_move_its_topics() -> None:
    with NodeHarness(Shouter, namespace="left", remap={"chatter": "/talk"}) as h:
        h.publish("talk", Text(text="hi"))
        assert [m.text for m in h.published("left/shout")] == ["HI!"]


def test_bad_params_are_refused_before_it_runs() -> None:
    with pytest.raises(palpa.ParamError, match="every"):
        NodeHarness(Shouter, {"every": 0})
    with pytest.raises(palpa.ParamError, match="suffix"):
        NodeHarness(Shouter, {"suffix": 3})
