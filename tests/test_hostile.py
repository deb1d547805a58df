"""Hostile frames against a live node's receive path: what an attacker with a plain pyzmq client can send must never
stop a node, never push a counter past what a heartbeat encodes, and never wedge a controller (issue 22)."""

from __future__ import annotations

import math

import msgpack
import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import palpa
from messages import PressureCommand, PressureState, Text
from nodes.mapping.map_aggregator import MapAggregator
from nodes.probe.pressure_controller import PressureController
from palpa.net.wire import COUNTER_MAX, msgpack_array
from palpa.runtime_msgs import Heartbeat
from palpa.testing import GraphHarness, NodeHarness

U64 = 2**64 - 1


def header(seq: int, node: str = "evil", type_: str = "Text") -> bytes:
    return msgpack.packb({"type": type_, "seq": seq, "stamp": 1, "node": node})


class Listener(palpa.Node):
    def setup(self) -> None:
        self.texts: list[str] = []
        self.subscribe("chatter", self.on_text)
        self.subscribe_raw("chat", lambda m: None)

    def on_text(self, msg: Text) -> None:
        self.texts.append(msg.text)


def beat(g: GraphHarness) -> None:
    """Every node sends its heartbeat now (they go on the wall clock, not the harness's mock clock)."""
    for node in g.nodes:
        node._heartbeat()
    g.spin()


def heartbeat_of(g: GraphHarness, name: str) -> Heartbeat:
    return [h for h in g.published("_palpa/heartbeat", Heartbeat) if h.node == name][-1]


def test_empty_batch_is_counted_and_the_subscriber_lives() -> None:
    with NodeHarness(Listener) as h:
        h.publish_raw([b"chatter", b"\x90", b"\x90"])
        h.publish_raw([b"chatter", header(1), msgpack.packb({"text": "still here"})])
        stats = h.node.counters()["chatter"]
        assert stats.decode_errors == 1 and "batch of 0 messages" in stats.last_error
        assert h.node.texts == ["still here"]
        assert h.node._rx.internal_errors == 0


def test_extreme_sequence_numbers_saturate_and_heartbeats_still_encode() -> None:
    with NodeHarness(Listener, heartbeat_s=1.0) as h:
        for seq in (1, U64, 1, U64, 1, U64):
            h.publish_raw([b"chatter", header(seq), msgpack.packb({"text": str(seq)})])
        stats = h.node.counters()["chatter"]
        assert stats.gaps == COUNTER_MAX and stats.restarts == 2
        beat(h)
        hb = heartbeat_of(h, "listener")
        assert hb.counters["chatter"].gaps == COUNTER_MAX
        # a sequence number no msgpack uint64 holds (or a negative one) is a bad header, not a counter
        h.publish_raw([b"chatter", msgpack.packb({"type": "Text", "seq": -1, "stamp": 1, "node": "x"}),
                       msgpack.packb({"text": "neg"})])
        assert h.node.counters()["chatter"].decode_errors == 1


def test_a_failed_publish_leaves_no_half_batch() -> None:
    class Pub(palpa.Node):
        def setup(self) -> None:
            self.out = self.publisher("chatter", Text, batch=8)

    with NodeHarness(Pub) as h:
        with pytest.raises(OverflowError):
            h.node.out.publish(Text(text="x", stamp_ns=2**70))
        assert h.node.out.seq == 0
        h.node.out.publish(Text(text="ok"))
        h.node.out.flush()  # raised IndexError when the header of the failed message stayed pending
        h.spin()
        assert [m.text for m in h.published("chatter")] == ["ok"]


@pytest.mark.parametrize("field", ["rate_kpa_s", "setpoint_kpa"])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_command_is_rejected_at_decode_and_the_controller_keeps_publishing(field: str,
                                                                                    value: float) -> None:
    with NodeHarness(PressureController, {"startup": "hold", "setpoint_kpa": 20.0}) as h:
        cmd = {"mode": "ramp", "setpoint_kpa": 30.0, "rate_kpa_s": 5.0, field: value}
        h.publish_raw([b"pressure/command", header(1, type_="PressureCommand"), msgpack.packb(cmd)])
        assert h.node.counters()["pressure/command"].decode_errors == 1
        h.advance(1.0)
        assert h.node.handler_errors == 0
        states = h.published("pressure/state", PressureState)
        assert states and all(math.isfinite(s.setpoint_kpa) for s in states)
        assert states[-1].mode == "hold"


def test_finite_types_reject_nan_where_it_means_nothing_and_keep_it_where_it_means_no_data() -> None:
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(msgpack.packb({"mode": "hold", "setpoint_kpa": math.nan}), type=PressureCommand)
    assert palpa.lookup("StiffnessMap") is not None
    sm = msgspec.msgpack.decode(msgpack.packb({"stamp_ns": 1, "unit": "kPa", "x_mm": [0.0], "y_mm": [0.0],
                                              "stiffness": [math.nan], "count": [0], "spread": [math.nan],
                                              "samples": 0}), type=palpa.lookup("StiffnessMap"))
    assert math.isnan(sm.stiffness[0])  # type: ignore[attr-defined]


# -- property-based fuzz -------------------------------------------------------------------------------------------
TOPICS = [b"chatter", b"chatterX", b"chat", b"pressure/command", b"stiffness/sample", b"robot/plan",
          b"robot/scan_status", b"_palpa/heartbeat", b""]
TYPES = ["Text", "PressureCommand", "StiffnessSample", "ScanPlan", "ScanStatus", "Heartbeat", "Nope", ""]

numbers = st.one_of(st.integers(min_value=-(2**63), max_value=U64), st.floats(allow_nan=True, allow_infinity=True))
values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8), st.binary(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12,
)
payload_maps = st.one_of(
    st.dictionaries(st.sampled_from(["text", "mode", "setpoint_kpa", "rate_kpa_s", "stamp_ns", "x_mm", "value",
                                     "valid", "model", "unit", "waypoints", "state", "progress"]), values,
                    max_size=6),
    st.just({"mode": "ramp", "setpoint_kpa": 1e308, "rate_kpa_s": 1e-308}),
    st.just({"text": "hi"}),
)
headers = st.fixed_dictionaries(
    {"type": st.sampled_from(TYPES), "seq": st.integers(min_value=0, max_value=U64),
     "stamp": st.integers(min_value=-(2**63), max_value=U64), "node": st.sampled_from(["evil", "a", ""])},
    optional={"latched": st.booleans()},
)


def _pack(v: object) -> bytes:
    return bytes(msgpack.packb(v))


single = st.builds(lambda t, h, p, blobs: [t, _pack(h), _pack(p), *blobs], st.sampled_from(TOPICS), headers,
                   payload_maps, st.lists(st.binary(max_size=8), max_size=2))
batches = st.builds(
    lambda t, items, extra: [t, msgpack_array([_pack(h) for h, _ in items]),
                             msgpack_array([_pack(p) for _, p in items + extra])],
    st.sampled_from(TOPICS), st.lists(st.tuples(headers, payload_maps), max_size=5),
    st.lists(st.tuples(headers, payload_maps), max_size=1))
garbage = st.lists(st.binary(max_size=24), max_size=5).map(lambda fs: [b"chatter", *fs])
raw_garbage = st.builds(lambda t, fs: [t, *fs], st.sampled_from(TOPICS), st.lists(st.binary(max_size=24), max_size=4))
frames_st = st.one_of(single, batches, garbage, raw_garbage)


@pytest.fixture(scope="module")
def graph() -> GraphHarness:
    g = GraphHarness()
    g.add(Listener, heartbeat_s=1.0)
    g.add(PressureController, {"startup": "hold", "setpoint_kpa": 20.0, "rate_hz": 5.0}, heartbeat_s=1.0)
    g.add(MapAggregator, heartbeat_s=1.0)
    return g


FUZZ = {"frames": 0}


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(st.lists(frames_st, min_size=1, max_size=6))
def test_fuzzed_frames_never_stop_a_node_and_counters_stay_encodable(graph: GraphHarness,
                                                                    envelopes: list[list[bytes]]) -> None:
    for frames in envelopes:
        graph.publish_raw(frames)
        FUZZ["frames"] += 1
    graph.clear()
    graph.advance(0.5)
    beat(graph)  # every node's heartbeat must encode
    for node in graph.nodes:
        assert node._rx.internal_errors == 0, node.name
        assert not node.is_shutdown, node.name
        hb = heartbeat_of(graph, node.name)
        for counters in hb.counters.values():
            assert 0 <= counters.gaps <= COUNTER_MAX and 0 <= counters.duplicates <= COUNTER_MAX
    states = graph.published("pressure/state", PressureState)
    assert states and all(math.isfinite(s.setpoint_kpa) and s.setpoint_kpa <= s.max_kpa for s in states)


# -- restarts ------------------------------------------------------------------------------------------------------
def test_a_restarted_publishers_first_message_is_delivered_not_dropped_as_a_duplicate() -> None:
    with GraphHarness() as g:
        listener = g.add(Listener)
        for incarnation in range(2):
            talker = g.add(palpa.Node, name="scanner")
            pub = talker.publisher("chatter", Text, latched=True)
            pub.publish(Text(text=f"plan from incarnation {incarnation}"))
            g.spin()
            talker.close(0)
            g.nodes.remove(talker)
        assert listener.texts == ["plan from incarnation 0", "plan from incarnation 1"]
        stats = listener.counters()["chatter"]
        assert stats.restarts == 1 and stats.duplicates == 0


def test_incarnation_is_optional_on_the_wire_and_ignored_by_plain_readers() -> None:
    with NodeHarness(Listener) as h:
        # an older publisher (no "inc"): seq 1, 1 is a duplicate as before
        for _ in range(2):
            h.publish_raw([b"chatter", header(1, node="old"), msgpack.packb({"text": "old"})])
        assert h.node.texts == ["old"] and h.node.counters()["chatter"].duplicates == 1
        for inc in (7, 7, 8):
            h.publish_raw([b"chatter", msgpack.packb({"type": "Text", "seq": 1, "stamp": 1, "node": "new",
                                                       "inc": inc}), msgpack.packb({"text": f"inc {inc}"})])
        assert h.node.texts == ["old", "inc 7", "inc 8"]
        assert h.node.counters()["chatter"].restarts == 1
    tpl = palpa.net.wire.HeaderTemplate("Text", "n", True, 42)
    assert msgpack.unpackb(tpl.pack(3, 4)) == {"type": "Text", "node": "n", "latched": True, "inc": 42, "seq": 3,
                                              "stamp": 4}
