"""The recorder's subscription on the bus: the runtime topics its filter never takes (a lockstep's ticks and acks,
half of a simulation's messages) are left out by the bus itself, every topic it records still arrives."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from palpa.address import BusAddress
from palpa.bus import Bus
from palpa.node import Node
from palpa.params_runtime import PARAMS_TOPIC
from palpa.record.format import TopicFilter, prefixes_except
from palpa.record.reader import iter_bag
from palpa.record.recorder import Recorder
from palpa.runtime_msgs import CLOCK_ACK_TOPIC, CLOCK_TOPIC, LOG_TOPIC, tick_topic
from palpa.transport import Delivery
from palpa.wire import Header
from tests.procs import short_ipc_base, wait_until

LOCKSTEP_EXCLUDE = ["_palpa/clock.*", "_palpa/tick/.*", "_palpa/lockstep"]  # launch/scan_sim.yaml's record:
LOCKSTEP = [tick_topic("scanner"), CLOCK_ACK_TOPIC, CLOCK_TOPIC]


def _covered(prefixes: list[bytes], topic: str) -> bool:
    return any(topic.encode().startswith(p) for p in prefixes)


def _some_topics() -> list[str]:
    rng = random.Random(7)
    names = ["robot/pose", "_odd", "_palpa_x", "_palpa", "_palpa/log", "_palpa/params", "_palpa/heartbeat",
             "_palpa/log2", "_palpa/lg", "_palpa/tick/x/", "_palpa/srv/a", "x", "\u00e9t\u00e9/a", "/abs", "a" * 200]
    names += ["".join(chr(rng.randrange(1, 0x250)) for _ in range(rng.randrange(1, 12))) for _ in range(2000)]
    names += ["_palpa/" + "".join(chr(rng.randrange(32, 127)) for _ in range(rng.randrange(1, 12)))
              for _ in range(500)]
    return names


@pytest.mark.parametrize(("include", "exclude"), [
    ([], LOCKSTEP_EXCLUDE),
    ([], []),
    (["probe/.*", "_palpa/heartbeat"], []),
    (["_palpa/tick/.*", "chatter"], ["_palpa/tick/b.*"]),
    (["^_palpa/(log|srv/.*)"], []),
    (["_palpa/log|_palpa/srv/.*"], []),
    (["_palpa/lo?g"], []),
])
def test_bus_prefixes_cover_every_topic_the_filter_takes(include: list[str], exclude: list[str]) -> None:
    f = TopicFilter(include, exclude, always=(LOG_TOPIC, PARAMS_TOPIC))
    prefixes = f.bus_prefixes()
    beginnings = {"_palpa"[:n] for n in range(1, 7)}  # the documented blind spot of a prefix subscription
    for topic in _some_topics() + LOCKSTEP:
        if f(topic) and topic not in beginnings:
            assert _covered(prefixes, topic), topic


def test_bus_prefixes_leave_out_the_runtime_topics_never_taken() -> None:
    prefixes = TopicFilter([], LOCKSTEP_EXCLUDE, always=(LOG_TOPIC, PARAMS_TOPIC)).bus_prefixes()
    for topic in [*LOCKSTEP, "_palpa/heartbeat", "_palpa/srv/a", "_palpa/join/x/1.0"]:
        assert not _covered(prefixes, topic), topic
    for topic in ["robot/pose", LOG_TOPIC, PARAMS_TOPIC, "_odd", "_palpa_x"]:
        assert _covered(prefixes, topic), topic
    # a pattern naming runtime topics brings them back
    asked = TopicFilter(["_palpa/tick/.*"], []).bus_prefixes()
    assert _covered(asked, tick_topic("scanner")) and not _covered(asked, CLOCK_ACK_TOPIC)
    assert prefixes_except(b"_p") == [bytes((b,)) for b in range(256) if b != 0x5F] + \
        [b"_" + bytes((b,)) for b in range(256) if b != 0x70]


def test_the_recorder_never_receives_a_lockstep_frame_and_records_the_rest(tmp_path: Path) -> None:
    """On a real bus: the recorder with the demo's exclusions gets no tick, ack or clock message at its socket, and
    records every other topic it takes, runtime ones (the log, parameter changes) included."""
    bus = Bus(BusAddress.parse(f"ipc://{short_ipc_base()}"))
    address = bus.start()
    out = tmp_path / "r.mcap"
    rec = Recorder("recorder", {"output": str(out), "exclude": LOCKSTEP_EXCLUDE}, bus=address, heartbeat_s=0)
    src = Node(name="src", bus=address, heartbeat_s=0)
    at_socket: list[bytes] = []
    poll = rec.transport.poll

    def spy(timeout_s: float) -> list[Delivery]:
        got = poll(timeout_s)
        at_socket.extend(d.frames[0] for d in got)
        return got

    rec.transport.poll = spy  # type: ignore[method-assign]
    try:
        kept = ["robot/pose", "_odd", LOG_TOPIC, PARAMS_TOPIC]
        t = src.transport
        wait_until(lambda: all(t.has_subscribers(k.encode()) for k in kept), 10, "the recorder's subscriptions",
                   step=lambda: (src.spin_once(0.01), rec.spin_once(0.01)))
        for i, topic in enumerate(LOCKSTEP + kept + ["end"]):
            src.publish_raw(topic, Header(type="Text", seq=i + 1, stamp=i, node="src"), b"\x81\xa4text\xa1x")
        wait_until(lambda: b"end" in at_socket, 10, "the last message at the recorder",
                   step=lambda: rec.spin_once(0.01))
    finally:
        rec.close(0)
        src.close(0)
        bus.stop()
    assert not [f for f in at_socket if f.decode() in LOCKSTEP]
    assert {m.topic for m in iter_bag([out])} >= {*kept, "end"}
