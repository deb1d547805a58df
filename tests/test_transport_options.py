"""Per-node transport options (high-water marks, busy polling): from the environment, the command line and launch
files, applied to the node's sockets, and what a full receive queue does (drops seen as sequence gaps)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import pytest

import palpa
from messages import Text
from palpa.errors import BusError, LaunchError
from palpa.launch import load_launch
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.net.transport import TransportOptions, ZmqTransport
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from tests.procs import ProcessGroup, bus_spec, palpa_cmd, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


def test_options_from_defaults_environment_and_flags() -> None:
    assert TransportOptions.from_env({}) == TransportOptions(10_000, 10_000, 0)
    env = TransportOptions(50, 7, 200).to_env()
    assert list(env) == ["PALPA_TRANSPORT"]  # one value, not one variable per option
    assert TransportOptions.from_env(env) == TransportOptions(50, 7, 200)
    assert TransportOptions.from_env(env, rcvhwm=0, sndhwm=None) == TransportOptions(50, 0, 200)
    with pytest.raises(BusError, match=r"PALPA_TRANSPORT='.*': Expected `int`, got `str` - at `\$.rcvhwm`"):
        TransportOptions.from_env({"PALPA_TRANSPORT": '{"rcvhwm": "lots"}'})
    with pytest.raises(BusError, match=r"Object contains unknown field `rcvhmw`"):
        TransportOptions.from_env({"PALPA_TRANSPORT": '{"rcvhmw": 5}'})
    with pytest.raises(BusError, match="transport option busy_poll_us: expected an integer >= 0, got -1"):
        TransportOptions(busy_poll_us=-1)


def test_the_bounds_are_declared_once_and_checked_on_every_path() -> None:
    """busy_poll_us <= 1e6: constructed, decoded from the environment, and given as a flag over the environment."""
    with pytest.raises(BusError, match="busy_poll_us: expected an integer <= 1000000"):
        TransportOptions(busy_poll_us=1_000_001)
    with pytest.raises(BusError, match=r"Expected `int` <= 1000000 - at `\$.busy_poll_us`"):
        TransportOptions.from_env({"PALPA_TRANSPORT": '{"busy_poll_us": 1000001}'})
    with pytest.raises(BusError, match="busy_poll_us: expected an integer <= 1000000"):
        TransportOptions.from_env({}, busy_poll_us=1_000_001)
    with pytest.raises(BusError, match="max_msg_bytes: expected an integer >= 1024"):
        TransportOptions(max_msg_bytes=10)
    assert TransportOptions(busy_poll_us=1_000_000).busy_poll_us == 1_000_000


def test_node_sockets_get_the_options(ipc_bus: BusAddress, monkeypatch: pytest.MonkeyPatch) -> None:
    with palpa.Node(name="explicit", bus=ipc_bus, heartbeat_s=0,
                    transport_options=TransportOptions(sndhwm=123, rcvhwm=45)) as node:
        transport = node.transport
        assert isinstance(transport, ZmqTransport)
        assert (transport._pub.sndhwm, transport._sub.rcvhwm) == (123, 45)
    monkeypatch.setenv("PALPA_TRANSPORT", '{"rcvhwm": 77}')
    with palpa.Node(name="from_env", bus=ipc_bus, heartbeat_s=0) as node:
        assert isinstance(node.transport, ZmqTransport) and node.transport._sub.rcvhwm == 77


def test_launch_file_sets_them_through_the_environment(tmp_path: Path) -> None:
    f = tmp_path / "g.yaml"
    f.write_text("nodes:\n"
                 "  - {name: fast, node: nodes.demo:Listener, transport: {rcvhwm: 100000, busy_poll_us: 500}}\n"
                 "  - {name: plain, node: nodes.demo:Talker}\n")
    plan = load_launch(f)
    fast, plain = plan.nodes
    assert fast.transport == TransportOptions(rcvhwm=100000, busy_poll_us=500) and plain.transport is None
    env = fast.child_env({}, bus=None, run_dir=tmp_path, python_path=[])
    assert TransportOptions.from_env(env) == fast.transport
    assert "PALPA_TRANSPORT" not in plain.child_env({}, bus=None, run_dir=tmp_path, python_path=[])
    assert fast.as_dict()["transport"] == {"rcvhwm": 100000, "busy_poll_us": 500}

    f.write_text("nodes:\n  - {name: bad, node: nodes.demo:Listener, transport: {rcvhwm: -1}}\n")
    with pytest.raises(LaunchError, match=r"g.yaml:2:.*rcvhwm.*>= 0"):
        load_launch(f)


@contextlib.contextmanager
def unbounded_bus() -> Iterator[BusAddress]:
    """A bus whose proxy never drops (hwm 0): what reaches it reaches an unbounded subscriber."""
    with Bus(bus_spec("ipc"), hwm=0) as b:
        assert b.address is not None
        yield b.address


def _burst_then_drain(bus: BusAddress, rcvhwm: int, n: int) -> tuple[int, int, int]:
    """Publish n messages while the subscriber is not reading, then drain; returns (received, gaps, span): span
    is the number of sequence numbers from the first message received to the last one.

    Before the burst the publisher sends a marker until one arrives (the subscription is then in place); after it,
    another until one arrives, so every drop of the burst sits before a received message and counts as a gap."""
    sub_node = palpa.Node(name="slow", bus=bus, heartbeat_s=0, transport_options=TransportOptions(rcvhwm=rcvhwm))
    pub_node = palpa.Node(name="fast", bus=bus, heartbeat_s=0, transport_options=TransportOptions(sndhwm=0))
    try:
        got: list[str] = []
        seqs: list[int] = []

        def on_text(msg: Text) -> None:
            assert sub.last_header is not None
            seqs.append(sub.last_header.seq)
            got.append(msg.text)

        sub = sub_node.subscribe("burst", Text, on_text)
        pub = pub_node.publisher("burst", Text)

        def marker_arrived(text: str) -> bool:
            if not got or got[-1] != text:
                pub.publish(Text(text=text))
            return bool(got) and got[-1] == text

        wait_until(lambda: marker_arrived("start"), 10, "the first message", step=lambda: sub_node.spin_once(0.01))
        for i in range(n):
            pub.publish(Text(text=str(i)))
        wait_until(lambda: marker_arrived("end"), 30, "the marker after the burst",
                   step=lambda: sub_node.spin_once(0.01))
        stats = sub_node.counters()["burst"]
        assert seqs == sorted(seqs)
        return stats.received, stats.gaps, seqs[-1] - seqs[0] + 1
    finally:
        pub_node.close(0)
        sub_node.close(0)


def test_a_full_receive_queue_drops_and_the_subscriber_counts_every_drop(ipc_bus: BusAddress) -> None:
    # the node's 10-message queue fills, then the proxy's queue towards it (10 000), and the proxy drops
    received, gaps, span = _burst_then_drain(ipc_bus, rcvhwm=10, n=40_000)
    assert gaps > 0, "a 10-message queue should have overflowed during a 40 000-message burst"
    assert span > 40_000 and received + gaps == span  # every message is either delivered or counted as missing


def test_an_unbounded_receive_queue_loses_nothing() -> None:
    with unbounded_bus() as bus:
        received, gaps, span = _burst_then_drain(bus, rcvhwm=0, n=40_000)
    assert gaps == 0 and received == span > 40_000


def test_node_process_takes_flags_and_refuses_bad_values(ipc_bus: BusAddress, procs: ProcessGroup,
                                                          env_for) -> None:  # type: ignore[no-untyped-def]
    """`palpa run ... --rcvhwm N --busy-poll-us US` runs; a bad value is a one-line error and exit 2."""
    watch = palpa.Node(name="watch", bus=ipc_bus, heartbeat_s=0)
    try:
        beats: dict[str, Heartbeat] = {}
        watch.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda hb: beats.__setitem__(hb.node, hb))
        ok = procs.start(palpa_cmd("run", "nodes.demo:Listener", "--rcvhwm", "5", "--busy-poll-us", "100"),
                         env=env_for(ipc_bus))
        wait_until(lambda: "listener" in beats, 20, "the listener's heartbeat", step=lambda: watch.spin_once(0.05))
        assert ok.stop(10) == 0
        bad = procs.start(palpa_cmd("run", "nodes.demo:Listener"),
                          env={**env_for(ipc_bus), "PALPA_TRANSPORT": '{"rcvhwm": "x"}'})
        assert bad.wait(20) == 2
        assert "Expected `int`, got `str` - at `$.rcvhwm`" in bad.output()
    finally:
        watch.close(0)


def test_a_fast_timer_sleeps_between_ticks_instead_of_spinning(ipc_bus: BusAddress) -> None:
    """A 1 kHz timer: the node waits in the kernel (ms polls, then a sub-ms select) rather than polling in a
    loop through the last fraction of every period (which cost a whole core)."""
    with palpa.Node(name="ticker", bus=ipc_bus, heartbeat_s=0) as node:
        ticks = [0]
        node.timer(0.001, lambda: ticks.__setitem__(0, ticks[0] + 1))
        transport = node.transport
        polls = [0]
        real_poll = transport.poll

        def counting_poll(timeout_s: float) -> list:  # type: ignore[type-arg]
            polls[0] += 1
            return real_poll(timeout_s)

        transport.poll = counting_poll  # type: ignore[method-assign]
        wait_until(lambda: ticks[0] >= 100, 20, "100 ticks", step=lambda: node.spin_once(0.1))
        # spin_once polls twice per call; a call wakes for a tick, for the ms-rounded part of a wait, or for input
        assert polls[0] <= 8 * ticks[0], f"{polls[0]} polls for {ticks[0]} ticks"


def test_a_busy_polling_node_receives_everything_and_still_runs_its_timers(ipc_bus: BusAddress) -> None:
    with palpa.Node(name="spinner", bus=ipc_bus, heartbeat_s=0,
                    transport_options=TransportOptions(busy_poll_us=20_000)) as node, \
            palpa.Node(name="talker", bus=ipc_bus, heartbeat_s=0) as talker:
        got: list[str] = []
        ticks = [0]
        node.subscribe("chatter", Text, lambda m: got.append(m.text))
        node.timer(0.005, lambda: ticks.__setitem__(0, ticks[0] + 1))
        pub = talker.publisher("chatter", Text)

        def hello_heard() -> bool:
            if not got:
                pub.publish(Text(text="hello"))
            return bool(got)

        wait_until(hello_heard, 10, "the subscription", step=lambda: node.spin_once(0.05))
        for i in range(200):
            pub.publish(Text(text=str(i)))
        numbers = lambda: [t for t in got if t != "hello"]  # noqa: E731 - more hellos may still be on the way
        wait_until(lambda: len(numbers()) >= 200 and ticks[0] >= 5, 10, "every message and five ticks",
                   step=lambda: node.spin_once(0.05))
        assert numbers() == [str(i) for i in range(200)]
        assert node.counters()["chatter"].gaps == 0
