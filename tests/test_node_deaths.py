"""Nodes dying mid-scan (issue 22): a dead clock, a silent pressure controller, a respawned map, a dead recorder.
Nothing may freeze, and nothing may end clean after losing data."""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

import pytest

import palpa
from palpa.runtime_msgs import ClockTick
from palpa.testing import MemoryBus
from tests.procs import ProcessGroup, wait_until

pytestmark = pytest.mark.system  # processes, sockets or ur_rtde: make test-system


class Ticker(palpa.Node):
    def setup(self) -> None:
        self.ticks = 0
        self.timer(0.01, self.tick)

    def tick(self) -> None:
        self.ticks += 1


def sim_ticker(timeout_s: float) -> tuple[Ticker, palpa.Node, palpa.Publisher[ClockTick]]:
    """A sim-clock node with the wall-clock guard at ``timeout_s``, and a clock node to tick it."""
    bus = MemoryBus()
    node = Ticker(transport=bus.transport(), heartbeat_s=0, sim_clock=True, wait_for_clock_s=0,
                  sim_clock_timeout_s=timeout_s)
    clock = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    return node, clock, clock.publisher("_palpa/clock", ClockTick)


def test_a_sim_clock_node_stops_with_a_clear_error_when_simulated_time_stops() -> None:
    node, clock, pub = sim_ticker(0.3)
    logs: list[str] = []
    node.log.error = lambda msg, *a: logs.append(msg % a)  # type: ignore[method-assign]
    for i in range(20):
        pub.publish(ClockTick(sim_ns=1_000_000_000 + i * 10_000_000))
        node.spin_once(0)
    assert node.ticks >= 10 and not node.is_shutdown
    started = time.monotonic()
    wait_until(lambda: (node.spin_once(0.02), node.is_shutdown)[1], 10, "the node to notice the dead clock")
    assert time.monotonic() - started >= 0.3
    assert node.exit_code == 3 and "simulated time stopped" in logs[0] and "_palpa/clock" in logs[0]
    node.close(0)
    clock.close(0)


def test_a_tick_that_jumps_past_the_bound_is_refused_logged_and_counted() -> None:
    """One forged tick an hour ahead (or at 2^63-1) mid-run: refused (the node's time and timers stay where they
    are, the next real ticks go on), logged with the bound and counted. A forged tick that came through moved every
    timer of the graph an hour on and froze the lockstep graph."""
    node, clock, pub = sim_ticker(0)
    logs: list[str] = []
    node.log.error = lambda msg, *a: logs.append(msg % a)  # type: ignore[method-assign]
    t = 1_000_000_000
    for forged in (t + 3600 * 10**9, 2**63 - 1):
        for _ in range(5):
            t += 10_000_000
            pub.publish(ClockTick(sim_ns=t))
            node.spin_once(0)
        ticks = node.ticks
        pub.publish(ClockTick(sim_ns=forged))
        node.spin_once(0)
        assert node.clock.now_ns() == t and node.ticks == ticks and not node.is_shutdown
        t += 10_000_000
        pub.publish(ClockTick(sim_ns=t))
        node.spin_once(0)
        assert node.clock.now_ns() == t and node.ticks == ticks + 1
    assert node.sim_time is not None and node.sim_time.refused_jumps == 2
    assert node.refusals == {"clock_jump": 2}  # in its heartbeats: palpa node info shows it
    assert "refused" in logs[0] and "3600 s ahead" in logs[0] and "PALPA_SIM_CLOCK_MAX_JUMP_S" in logs[0]
    # a jump within the bound is time moving on (an idle node hears the clock once a wall second)
    pub.publish(ClockTick(sim_ns=t + 50 * 10**9))
    node.spin_once(0)
    assert node.clock.now_ns() == t + 50 * 10**9 and node.sim_time.refused_jumps == 2
    node.close(0)
    clock.close(0)


def test_a_message_whose_instant_jumps_past_the_bound_does_not_move_time() -> None:
    """The event lockstep lets a node learn time from the instant of the messages it handles: a message stamped an
    hour ahead is refused as a tick would be."""
    import msgspec

    from messages import Text
    from palpa.net.wire import Header

    bus = MemoryBus()
    node = Ticker(transport=bus.transport(), heartbeat_s=0, sim_clock=True, wait_for_clock_s=0,
                  sim_clock_timeout_s=0)
    heard: list[int] = []
    node.subscribe("chatter", Text, lambda m: heard.append(node.clock.now_ns()))
    clock = palpa.Node(name="clock", transport=bus.transport(), heartbeat_s=0)
    clock.publisher("_palpa/clock", ClockTick).publish(ClockTick(sim_ns=10**9))
    node.spin_once(0)
    forger = palpa.Node(name="forger", transport=bus.transport(), heartbeat_s=0)
    for seq, ahead_s in ((1, 1), (2, 3600)):
        forger.publish_raw("chatter", Header(type="Text", seq=seq, stamp=1, node="forger", at=(1 + ahead_s) * 10**9),
                           msgspec.msgpack.encode(Text(text="hi")))
        node.spin_once(0)
    assert heard == [2 * 10**9, 2 * 10**9]  # the message is handled; its instant an hour on is not taken
    assert node.sim_time is not None and node.sim_time.refused_jumps == 1
    for n in (node, clock, forger):
        n.close(0)


def test_a_held_clock_is_not_a_dead_clock() -> None:
    """Lockstep holds simulated time back but keeps ticking: the guard counts ticks, not time's progress."""
    node, clock, pub = sim_ticker(0.2)
    deadline = time.monotonic() + 0.6
    while time.monotonic() < deadline:
        pub.publish(ClockTick(sim_ns=1_000_000_000))
        node.spin_once(0.02)
    assert not node.is_shutdown
    node.close(0)
    clock.close(0)


def test_a_respawned_node_or_a_failure_reported_on_stop_never_ends_the_launch_clean(procs: ProcessGroup,
                                                                                   tmp_path: Path) -> None:
    from tests.test_launch_supervisor import launch, prog, write

    file = write(tmp_path, f"""
        nodes:
          - {{name: phoenix, cmd: {prog("crash_once", str(tmp_path / "crashed"))}, respawn: true,
              respawn_delay: 0.1}}
          - {{name: mapper, cmd: {prog("fail_on_stop")}}}
          - {{name: quitter, cmd: {prog("quit", "0", "2.0")}, required: true}}
    """)
    proc = launch(procs, file, tmp_path / "run")
    assert proc.wait(30) == 1
    out = proc.output()
    assert "restarted mid-run (data lost while down): phoenix" in out
    assert re.search(r"! mapper\s+stopped on SIGINT, reporting failure \(exit code 4\)", out), out
    # the summary says why, in the node's own words (its last ERROR line)
    assert "failed: mapper (palpa.node.mapper: the map is INCOMPLETE and may be wrong: stopped at 20 %)" in out


def test_a_killed_recorder_stops_a_recording_launch_and_leaves_a_readable_file(procs: ProcessGroup,
                                                                               tmp_path: Path) -> None:
    from mcap.reader import make_reader

    from tests.test_launch_supervisor import launch, prog, wait_started, write

    file = write(tmp_path, f"""
        record: {{}}
        nodes:
          - {{name: talker, node: nodes.demo:Talker, params: {{rate_hz: 100.0}}}}
          - {{name: steady, cmd: {prog("steady")}}}
    """)
    run_dir = tmp_path / "run"
    proc = launch(procs, file, run_dir)
    pids = wait_started(run_dir, "recorder", "talker")
    wait_until(lambda: (run_dir / "recording.mcap").stat().st_size > 4000, 20, "something recorded")
    os.kill(pids["recorder"], signal.SIGKILL)
    assert proc.wait(30) == 1
    out = proc.output()
    assert "the recorder ended (killed by SIGKILL); record.required: the rest of the run would go unrecorded" in out
    with open(run_dir / "recording.mcap", "rb") as fh:  # as it was left, by the official reader
        assert any(ch.topic == "chatter" for _, ch, _ in make_reader(fh).iter_messages())


def test_a_node_process_that_stops_still_delivers_what_it_had_queued(procs: ProcessGroup) -> None:
    """Closing a socket hands its queue to libzmq's I/O thread, which dies with the process: `palpa run` waits for
    the linger before exiting, or the tail of a burst is lost where no sequence gap shows it (found across hosts,
    bench/multihost.py)."""
    from messages import Text
    from palpa.net.bus import Bus
    from tests.procs import bus_spec, palpa_cmd

    with Bus(bus_spec("ipc")) as bus, palpa.Node(name="sink", bus=bus.address, heartbeat_s=0) as sink:
        got: list[str] = []
        sink.subscribe("test/burst", Text, lambda m: got.append(m.text.split(" ", 1)[0]))
        burst = procs.start(palpa_cmd("run", "tests.launch_node_classes:Burst", "--bus", str(bus.address),
                                       "-p", "n=1000"))
        wait_until(lambda: burst.popen.poll() is not None, 30, "the burst node to finish",
                   step=lambda: sink.spin_once(0.01))
        assert burst.popen.returncode == 0, burst.output()
        # everything it sent is on its way now (the process is gone): drain, then count
        settled = wait_until(lambda: len(got) >= 1000 or None, 5, "the whole burst", step=lambda: sink.spin_once(0.01))
        assert settled and got == [str(i) for i in range(1000)]
