"""Forged, duplicate and out-of-order clock acks cannot steer the lockstep (issue 39): the clock believes an ack only
when it is bound to the identity of the node it reports on (palpa.timing.ackgate); every refusal is counted, logged
at a rate limit and shown by ``palpa node info``."""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import palpa
from nodes.demo import Talker
from palpa.cli.node import node_info_lines
from palpa.net.wire import Header
from palpa.node.endpoints import RawMessage
from palpa.runtime_msgs import (
    CLOCK_ACK_TOPIC,
    HEARTBEAT_TOPIC,
    ClockAck,
    ClockTick,
    Heartbeat,
    tick_topic,
)
from palpa.testing import MemoryBus
from palpa.timing.ackgate import MAX_SEQ_STEP, AckGate
from palpa.timing.acksign import MAC_BYTES, node_key, sign, verify
from palpa.timing.simclock import ClockSource
from tests.procs import wait_until
from tests.test_runtime_unit import clock_source

NOW = 5_000


def hdr(node: str, inc: int, seq: int) -> Header:
    return Header(type="ClockAck", seq=seq, stamp=1, node=node, inc=inc)


def ack(node: str = "n", sim_ns: int = 100, next_ns: int = 200, leaving: bool = False) -> ClockAck:
    return ClockAck(node=node, sim_ns=sim_ns, next_ns=next_ns, leaving=leaving)


def test_the_gate_binds_a_name_to_its_sender_and_incarnation_and_keeps_acks_in_order() -> None:
    gate = AckGate()
    assert gate.check(ack(), hdr("n", 7, 1), NOW) is None  # the first ack binds n to incarnation 7
    assert gate.check(ack(), hdr("mallory", 9, 1), NOW) == "not_sender"  # on behalf of n
    assert gate.check(ack(leaving=True), hdr("n", 8, 50), NOW) == "other_incarnation"  # a forged leave
    assert gate.check(ack(), hdr("n", 7, 1), NOW) == "out_of_order"  # a duplicate
    assert gate.check(ack(sim_ns=300), hdr("n", 7, 2), NOW) is None
    assert gate.check(ack(sim_ns=200), hdr("n", 7, 3), NOW) == "out_of_order"  # its time goes back
    assert gate.check(ack(sim_ns=300), hdr("n", 7, 2 + MAX_SEQ_STEP + 1), NOW) == "seq_jump"
    assert gate.check(ack(sim_ns=NOW + 1), hdr("n", 7, 3), NOW) == "not_issued"  # a time the clock never gave
    assert gate.check(ack(sim_ns=NOW), hdr("n", 7, 3), NOW) is None
    assert gate.refused == {"not_sender": 1, "other_incarnation": 1, "out_of_order": 2, "seq_jump": 1,
                            "not_issued": 1}
    assert gate.owns("n", 7) and not gate.owns("n", 8)


def test_a_respawned_node_takes_the_name_once_the_old_incarnation_is_gone_and_not_before() -> None:
    gate = AckGate()
    assert gate.check(ack(), hdr("n", 7, 1), NOW) is None
    assert gate.check(ack(sim_ns=150), hdr("n", 8, 1), NOW) == "other_incarnation"
    assert gate.check(ack(sim_ns=160), hdr("n", 8, 2), NOW) == "other_incarnation"
    waiting = gate.release("n")  # its old process is gone: the newer one's latest ack is checked again
    assert waiting is not None and waiting[1].seq == 2
    assert gate.check(*waiting, NOW) is None and gate.owns("n", 8)
    assert gate.check(ack(sim_ns=170), hdr("n", 7, 2), NOW) == "other_incarnation"  # the old one is out
    gate.release("n")  # dropped for silence, then acks again: in order with what it sent before
    assert gate.check(ack(sim_ns=170), hdr("n", 8, 2), NOW) == "out_of_order"
    assert gate.check(ack(sim_ns=170), hdr("n", 8, 3), NOW) is None


def test_outside_the_participants_a_node_is_believed_once_its_heartbeats_are_heard() -> None:
    gate = AckGate(frozenset({"talker"}))
    assert gate.check(ack("guest", next_ns=1), hdr("guest", 5, 1), NOW) == "not_present"  # an invented participant
    assert gate.heard("guest", 6) is None  # another incarnation's heartbeat does not vouch for it
    waiting = gate.heard("guest", 5)
    assert waiting is not None and gate.check(*waiting, NOW) is None
    assert gate.check(ack("talker"), hdr("talker", 3, 1), NOW) is None  # a participant needs no heartbeat


_names = st.sampled_from(["n", "m", "mallory"])
_forged = st.tuples(st.booleans(), _names, _names, st.integers(0, 2**32), st.integers(0, 2**64 - 1),
                    st.integers(-(2**63), 2**63 - 1), st.integers(-1, 2**63 - 1), st.booleans())


@settings(max_examples=300, deadline=None)
@given(st.lists(_forged, max_size=40), st.lists(st.integers(0, 3), min_size=1, max_size=40))
def test_no_forged_ack_about_a_bound_node_is_believed_and_every_real_one_is(forged: list[tuple[bool, str, str, int, int,
                                                                                                int, int, bool]],
                                                                         steps: list[int]) -> None:
    """The real node ``n`` (incarnation 7) acks in order, its time moving by ``steps``; between its acks, anything:
    acks about any name, from any sender name, incarnation, sequence number, time, deadline, leaving or not, or a
    replay of one of n's own earlier acks. Each of n's acks is believed; nothing else about n is, unless it copies
    n's header exactly with a later sequence number (what no check without authentication can tell apart)."""
    gate = AckGate()
    real: list[tuple[ClockAck, Header]] = []
    sim = 0
    for seq, step in enumerate(steps, start=1):
        sim += step
        mine = (ack("n", sim_ns=sim), hdr("n", 7, seq))
        assert gate.check(*mine, NOW) is None, f"n's ack {seq} refused"
        real.append(mine)
        for replay, about, sender, inc, fseq, fsim, fnext, leaving in forged[seq - 1::len(steps)]:
            if replay:
                f_ack, f_hdr = real[fseq % len(real)]
            else:
                f_ack = ClockAck(node=about, sim_ns=fsim, next_ns=fnext, leaving=leaving)
                f_hdr = hdr(sender, inc, fseq)
            copies = f_hdr.node == "n" and f_hdr.inc == 7 and f_hdr.seq > seq
            if f_ack.node == "n" and not copies:
                assert gate.check(f_ack, f_hdr, NOW) is not None, (f_ack, f_hdr)
            elif copies:
                return  # the limit of the gate: from here n races its impostor
            else:
                gate.check(f_ack, f_hdr, NOW)
            assert gate.owns("n", 7)


def _spin(nodes: list[palpa.Node], until: Callable[[], object], timeout_s: float = 20.0,
          between: Callable[[], object] | None = None) -> None:
    """Spin ``nodes`` (then ``between()``) until ``until()`` holds; the memory bus needs no time, so the deadline
    is only there to fail a test that would otherwise spin for good, with what it waited for."""

    def step() -> None:
        for n in nodes:
            n.spin_once(0)
        if between is not None:
            between()

    wait_until(until, timeout_s, "the test's condition", step=step)


def test_forged_duplicate_and_replayed_acks_neither_advance_nor_freeze_simulated_time() -> None:
    """A 10 Hz talker under the event lockstep, and three hostile clients acking at every turn of the loop: one
    under its own name on the talker's behalf (next timer an hour on, or 'leaving': time would skip the talker's
    deadlines), one under the talker's name from another process (another incarnation), one an invented participant
    whose timer is always due (time would freeze), and one replaying the talker's own earlier acks. The talker still
    gets every instant of its timer, each once, in order, and the clock counts every refusal by kind."""
    bus = MemoryBus()
    clock = ClockSource("clock", {"time_scale": 1000.0, "rate_hz": 1000.0, "participants": ["talker"]},
                        transport=bus.transport(), heartbeat_s=0)
    talker = Talker(name="talker", params={"rate_hz": 10.0}, transport=bus.transport(), heartbeat_s=0, sim_clock=True,
                    wait_for_clock_s=0)
    hostile = {name: palpa.Node(name=name, transport=bus.transport(), heartbeat_s=0)
               for name in ("mallory", "talker", "ghost")}
    forge = {name: n.publisher(CLOCK_ACK_TOPIC, ClockAck) for name, n in hostile.items()}
    captured: list[RawMessage] = []
    hostile["mallory"].subscribe_raw(CLOCK_ACK_TOPIC, captured.append)
    instants: list[ClockTick] = []
    hostile["ghost"].subscribe(tick_topic("talker"), ClockTick, instants.append)

    def attack() -> None:
        now = clock._sim
        forge["mallory"].publish(ClockAck(node="talker", sim_ns=now, next_ns=now + 3600 * 10**9))
        forge["mallory"].publish(ClockAck(node="talker", sim_ns=now, leaving=True))
        forge["talker"].publish(ClockAck(node="talker", sim_ns=now, next_ns=0, leaving=len(instants) % 2 == 1))
        forge["ghost"].publish(ClockAck(node="ghost", sim_ns=now, next_ns=1))
        real = [m for m in captured if m.header.node == "talker" and m.header.inc == talker.incarnation]
        if len(real) > 2:
            old = real[len(real) // 2]
            hostile["mallory"].publish_raw(CLOCK_ACK_TOPIC, old.header, old.payload)

    nodes: list[palpa.Node] = [clock, talker, *hostile.values()]
    _spin(nodes, lambda: len(instants) >= 10, between=attack)
    assert len(instants) >= 10, f"simulated time froze: {len(instants)} instants of the talker"
    start = instants[0].sim_ns - 100_000_000
    assert [t.sim_ns - start for t in instants[:10]] == [i * 100_000_000 for i in range(1, 11)]
    assert talker.out.seq >= 10
    refused = {k.removeprefix("clock_ack/"): n for k, n in clock.refusals.items()}
    assert {"not_sender", "other_incarnation", "not_present", "out_of_order"} <= set(refused) and \
        all(n > 0 for n in refused.values()), refused
    for n in nodes:
        n.close(0)


def test_refusals_go_out_in_the_heartbeats_and_node_info_shows_them() -> None:
    bus = MemoryBus()
    node = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=1.0)
    node.refusals["clock_ack/not_sender"] = 3
    listener = palpa.Node(name="tool", transport=bus.transport(), heartbeat_s=0)
    beats: list[Heartbeat] = []
    listener.subscribe(HEARTBEAT_TOPIC, Heartbeat, beats.append)
    _spin([node, listener], lambda: any(hb.node == "clock" for hb in beats), timeout_s=10.0)
    hb = next(hb for hb in beats if hb.node == "clock")
    assert hb.refused == {"clock_ack/not_sender": 3}
    lines = node_info_lines("clock", {"clock": hb})
    assert lines[-2:] == ["  Refused:", "    clock_ack/not_sender: 3"]
    for n in (node, listener):
        n.close(0)


def test_heartbeats_of_another_incarnation_do_not_keep_a_gone_participant_in(monkeypatch: pytest.MonkeyPatch) -> None:
    """The participant's process is gone; another process under its name heartbeats (alive, another pid): the clock
    still drops the participant once it has been silent ``check_after_s``, and time runs on."""
    wall, bus, src = clock_source(monkeypatch)
    src.pid_alive = lambda pid: pid == 5555
    slow, impostor = (palpa.Node(name="slow", transport=bus.transport(), heartbeat_s=0) for _ in range(2))
    slow.publisher(CLOCK_ACK_TOPIC, ClockAck).publish(ClockAck(node="slow", sim_ns=1_000_000_000))
    beat = {n: n.publisher(HEARTBEAT_TOPIC, Heartbeat) for n in (slow, impostor)}

    def heartbeat(node: palpa.Node, pid: int) -> None:
        beat[node].publish(Heartbeat(node="slow", pid=pid, host=socket.gethostname(), publishes={}, subscribes={},
                                     counters={}, sent={}, uptime_s=1.0))

    heartbeat(slow, 4242)  # the participant, whose process is gone
    src.spin_once(0)
    for wall[0] in range(100_000_000, 2_100_000_000, 100_000_000):  # the impostor heartbeats all along
        heartbeat(impostor, 5555)
        src.spin_once(0)
        src.sim_now_ns()
    assert src.sim_now_ns() > 1_020_000_000, "a gone participant kept in by another process's heartbeats"
    for n in (src, slow, impostor):
        n.close(0)


def test_a_respawned_nodes_ack_counts_as_soon_as_the_old_incarnation_leaves() -> None:
    """The old process still holds the name: the new one's ack is refused but kept; the old one's leaving ack (or
    its drop) frees the name, and the kept ack is believed then, without waiting for the new node to ack again."""
    bus = MemoryBus()
    clock = ClockSource("clock", {"time_scale": 1000.0}, transport=bus.transport(), heartbeat_s=0)
    old, new = (palpa.Node(name="n", transport=bus.transport(), heartbeat_s=0) for _ in range(2))
    acks = {n: n.publisher(CLOCK_ACK_TOPIC, ClockAck) for n in (old, new)}
    acks[old].publish(ClockAck(node="n", sim_ns=0, next_ns=0))
    clock.spin_once(0)
    acks[new].publish(ClockAck(node="n", sim_ns=0, next_ns=0))
    clock.spin_once(0)
    assert clock.refusals == {"clock_ack/other_incarnation": 1} and clock._gate.owns("n", old.incarnation)
    acks[old].publish(ClockAck(node="n", sim_ns=0, leaving=True))
    clock.spin_once(0)
    assert clock._gate.owns("n", new.incarnation) and "n" in clock._events
    for n in (clock, old, new):
        n.close(0)


def test_a_signature_binds_an_ack_to_its_node_its_message_number_and_its_content() -> None:
    master = bytes(range(32))
    key = node_key(master, "talker")
    real = ClockAck(node="talker", sim_ns=5, next_ns=9, sent={"chatter": 3}, subs=["x"])
    signed = msgspec.structs.replace(real, mac=sign(key, real, 7, 12))
    got = msgspec.msgpack.decode(msgspec.msgpack.encode(signed), type=ClockAck)  # as the clock receives it
    assert verify(key, got, 7, 12)
    assert not verify(key, got, 7, 13) and not verify(key, got, 8, 12)  # moved to another number / process
    assert not verify(key, msgspec.structs.replace(got, next_ns=10**15), 7, 12)  # its content changed
    assert not verify(key, msgspec.structs.replace(got, leaving=True), 7, 12)
    other = msgspec.structs.replace(real, node="map")  # the talker's key signs for the talker only
    assert not verify(node_key(master, "map"), msgspec.structs.replace(other, mac=sign(key, other, 7, 12)), 7, 12)
    assert not verify(key, real, 7, 12)  # unsigned
    assert not verify(node_key(bytes(32), "talker"), got, 7, 12)  # another run's key


def test_with_the_launchs_key_a_copied_header_or_a_name_taken_first_gets_nowhere(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The launcher gave the clock its run's master key and the talker its own key. A client takes the talker's
    name before it starts, then copies its header exactly (name, incarnation, next message number) with an ack of
    its own making: without the talker's key every one is refused, and the talker's timeline is whole."""
    master = bytes(range(32))
    monkeypatch.setenv("PALPA_CLOCK_MASTER_KEY", master.hex())
    bus = MemoryBus()
    clock = ClockSource("clock", {"time_scale": 1000.0, "rate_hz": 1000.0, "participants": ["talker"]},
                        transport=bus.transport(), heartbeat_s=0)
    squatter = palpa.Node(name="talker", transport=bus.transport(), heartbeat_s=0)
    squat = squatter.publisher(CLOCK_ACK_TOPIC, ClockAck)
    squat.publish(ClockAck(node="talker", sim_ns=0, next_ns=1))  # first under the name: a passed deadline
    clock.spin_once(0)
    monkeypatch.setenv("PALPA_CLOCK_KEY", node_key(master, "talker").hex())
    monkeypatch.setenv("PALPA_NODE_NAME", "talker")
    talker = Talker(name="talker", params={"rate_hz": 10.0}, transport=bus.transport(), heartbeat_s=0, sim_clock=True,
                    wait_for_clock_s=0)
    spy = palpa.Node(name="spy", transport=bus.transport(), heartbeat_s=0)
    instants: list[ClockTick] = []
    spy.subscribe(tick_topic("talker"), ClockTick, instants.append)
    seen: list[RawMessage] = []
    spy.subscribe_raw(CLOCK_ACK_TOPIC, seen.append)

    def copy_header() -> None:
        mine = [m.header for m in seen if m.header.inc == talker.incarnation]
        if mine:
            last = max(mine, key=lambda h: h.seq)
            forged = ClockAck(node="talker", sim_ns=clock._sim, next_ns=clock._sim + 3600 * 10**9,
                              mac=bytes(MAC_BYTES))
            spy.publish_raw(CLOCK_ACK_TOPIC, msgspec.structs.replace(last, seq=last.seq + 1),
                            msgspec.msgpack.encode(forged))
        squat.publish(ClockAck(node="talker", sim_ns=clock._sim, leaving=True))

    _spin([clock, talker, squatter, spy], lambda: len(instants) >= 10, between=copy_header)
    assert len(instants) >= 10, f"simulated time froze: {len(instants)} instants of the talker"
    start = instants[0].sim_ns - 100_000_000
    assert [t.sim_ns - start for t in instants[:10]] == [i * 100_000_000 for i in range(1, 11)]
    assert clock.refusals.get("clock_ack/bad_signature", 0) >= 10 and clock._gate.owns("talker", talker.incarnation)
    for n in (clock, talker, squatter, spy):
        n.close(0)


def test_the_launcher_gives_each_node_its_own_key_and_the_clock_the_runs_master(tmp_path: Path) -> None:
    from palpa.launch.loader import load_launch
    from palpa.launch.supervisor import Supervisor

    file = tmp_path / "sim.yaml"
    file.write_text("nodes:\n"
                    "  - {name: clock, node: 'palpa.timing.simclock:ClockSource'}\n"
                    "  - {name: talker, node: 'nodes.demo:Talker', env: {PALPA_SIM_CLOCK: '1'}}\n")
    plan = load_launch(file, run_dir=tmp_path / "run")
    runs = [Supervisor(plan, reaper=False) for _ in range(2)]
    envs = [{s.name: run.child_env(s) for s in plan.nodes} for run in runs]
    master = bytes.fromhex(envs[0]["clock"]["PALPA_CLOCK_MASTER_KEY"])
    assert "PALPA_CLOCK_MASTER_KEY" not in envs[0]["talker"]  # a node holds its own key only
    key = bytes.fromhex(envs[0]["talker"]["PALPA_CLOCK_KEY"])
    a = ClockAck(node="talker", sim_ns=1, next_ns=2)
    assert verify(node_key(master, "talker"), msgspec.structs.replace(a, mac=sign(key, a, 3, 4)), 3, 4)
    assert envs[1]["clock"]["PALPA_CLOCK_MASTER_KEY"] != envs[0]["clock"]["PALPA_CLOCK_MASTER_KEY"]  # per run
