"""The player node: republishes a recording with its original timing, sequence numbers, types and publishers.

``palpa play FILE`` and the launch-file node ``palpa.record.player:Player`` are the same class, so a launch file
can replace live sources with a recording while the downstream nodes run live (docs/recording.md).

Timing: message i is sent at ``t0 + (t_i - start) / rate`` where ``t_i`` is its recorded log time (``timeline:
log``) or its publisher's stamp (``timeline: publish``, never going back: a sim-clock graph's recorder logs on the
wall clock, so a run composed in one process at CPU speed is recorded compressed; its stamps are simulated time)
and ``start`` is the first message's time plus ``start_offset_s``. The loop polls the node's sockets (heartbeats, timers) while a message is more than 3 ms
away, then sleeps with microsecond resolution and spins only the last 0.3 ms, so the send-time error stays well
under 2 ms at 1 kHz even on a loaded machine (see ``_wait_until`` for why it does not spin longer). Each envelope keeps the
recorded type, sequence number and publisher name; its ``stamp`` is the new publish time. Latched messages are
re-published latched. With ``clock: true`` the node publishes ``ClockTick(sim_ns=<recorded time>)`` on
``_palpa/clock`` at ``clock_hz`` so nodes that follow the sim clock see the recording's time; while it waits to
start, the clock already runs (at wall speed, ending before the recording's start), so sim-clock nodes, which
wait for a first tick, can start and be heard.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import palpa
from palpa.errors import ParamError
from palpa.net.transport import ZmqTransport
from palpa.net.wire import Header
from palpa.node.node import Node
from palpa.node.params import convert_params
from palpa.record.format import TopicFilter
from palpa.record.reader import BagMessage, iter_bag, resolve_bag_paths
from palpa.runtime_msgs import CLOCK_TOPIC, HEARTBEAT_TOPIC, ClockTick, Heartbeat

__all__ = ["PlayerParams", "Player"]

_POLL_S = 0.003  # closer than this to a deadline, stop polling sockets (ms granularity) and sleep precisely
_SPIN_S = 0.0002  # the last stretch before a deadline is spun, not slept (wake-up latency)


class PlayerParams(palpa.Params):
    """Parameters of :class:`Player`."""

    file: str | list[str]
    """The recording: a .mcap file, a list of files, a split set's base name, or a directory."""
    rate: float = 1.0
    """Playback speed factor (2.0: twice as fast)."""
    loop: bool = False
    topics: list[str] = []
    """Regexes matched against whole topic names; empty plays every non-runtime topic."""
    exclude: list[str] = []
    remap: dict[str, str] = {}
    """Recorded topic -> topic to publish on."""
    start_offset_s: float = 0.0
    """Skip this many seconds from the start (latched messages before it are still published first)."""
    timeline: Literal["log", "publish"] = "log"
    """Pace by the recorder's log times, or by the publishers' stamps (simulated time for a sim-clock graph; see
    the module doc)."""
    clock: bool = False
    """Publish the recording's time on _palpa/clock (ClockTick)."""
    clock_hz: float = 1000.0
    """Clock ticks per second of playback (the time resolution sim-clock nodes' timers get, as with
    palpa.timing.simclock.ClockSource)."""
    exit_when_done: bool = True
    """Stop the node (exit 0) after the last message; otherwise keep running until stopped."""
    exit_delay_s: float = 0.5
    """With exit_when_done, when no downstream node can be checked (see ``drain_timeout_s``): keep the node up this
    long after the last message, so that in a launch file (player ``required: true``) the live downstream nodes
    finish with the last messages before they are stopped."""
    drain_timeout_s: float = 10.0
    """With exit_when_done: after the last message, wait until every downstream node (the ``wait_for`` nodes, and
    on a real bus every node whose readiness this player heard before it played) reports in its heartbeat that it
    took in everything played on the topics it subscribes to. One that makes no progress for this long (wall
    clock) lost messages: a warning says which and how many, and the player exits 1 (a replay that lost data
    does not end clean)."""
    realtime: bool = False
    """Ask the OS for real-time scheduling (SCHED_FIFO, priority 10) while playing, so other busy processes do not
    delay sends by whole time slices (measured at 1 kHz on a loaded 2-core VM: p99 3.8 ms -> 0.002 ms). Needs
    root or CAP_SYS_NICE; without them the player warns and plays normally."""
    wait_for: list[str] = []
    """Node names to hear (heartbeats) before playing: the downstream nodes of a launch file, so they have
    subscribed when the first message goes out."""
    ready_timeout_s: float = 10.0
    """Before playing, wait up to this long for the ``wait_for`` nodes to be ready and their subscriptions to have
    reached this node (so the first messages are not lost to ZeroMQ's slow joiner); then play anyway, with a
    warning."""


class Player(Node):
    """Plays a recording (a file, several files, a split set's base name, or a run directory) onto the bus."""

    Params = PlayerParams
    params: PlayerParams

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | PlayerParams | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # it is the source of sim time, never a follower
        where = f"node {name or 'player'!r}"
        p = convert_params(PlayerParams, params, where=where)
        if not p.rate > 0:
            raise ParamError(f"{where}: parameter 'rate' must be > 0, got {p.rate}")
        if p.start_offset_s < 0:
            raise ParamError(f"{where}: parameter 'start_offset_s' must be >= 0, got {p.start_offset_s}")
        if p.clock and not p.clock_hz > 0:
            raise ParamError(f"{where}: parameter 'clock_hz' must be > 0, got {p.clock_hz}")
        # before any socket: a missing file or bad parameter fails at once, bus or not
        self.paths: list[Path] = resolve_bag_paths(p.file if isinstance(p.file, str) else list(p.file))
        self._filter = TopicFilter(p.topics, p.exclude)
        super().__init__(name, p, **kwargs)

    def setup(self) -> None:
        p = self.params
        self._clock_pub = self.publisher(CLOCK_TOPIC, ClockTick) if p.clock else None
        self._waiting = set(p.wait_for)
        self._beats: dict[str, Heartbeat] = {}
        """The latest heartbeat of every node heard (what it subscribes to, and what it has taken in)."""
        self._downstream: set[str] = set()
        self.subscribe(HEARTBEAT_TOPIC, Heartbeat, self._on_heartbeat)
        self.played = 0
        self.passes = 0
        self.late_max_s = 0.0
        self._next_tick = 0.0
        self._serviced = 0.0
        self._hold_ns: int | None = None
        self._hold_wall = 0.0

    # -- helpers -----------------------------------------------------------------------------------------
    def _on_heartbeat(self, hb: Heartbeat) -> None:
        self._waiting.discard(hb.node)
        self._beats[hb.node] = hb

    def _not_ready(self) -> list[str]:
        """The ``wait_for`` nodes not ready for the first message: not heard (a heartbeat: set up) or, on a real
        bus, their subscriptions not yet heard by our publisher socket (their readiness probe, palpa.node.presence)."""
        t = self.transport
        return sorted(n for n in self.params.wait_for
                      if n in self._waiting or (isinstance(t, ZmqTransport) and not t.heard_join(n)))

    def _wait_ready(self) -> None:
        """Wait (bounded) until every ``wait_for`` node is ready: nothing played is dropped for lack of a route."""
        deadline = time.monotonic() + self.params.ready_timeout_s
        while (missing := self._not_ready()) and not self.is_shutdown:
            if time.monotonic() > deadline:
                self.log.warning("not ready after %.1f s (nodes %s not heard); playing anyway",
                                 self.params.ready_timeout_s, missing)
                return
            if self._clock_pub is not None:
                # sim-clock nodes wait for a first tick before they start, and their heartbeat timers run on
                # sim time: let the clock run at wall speed towards the recording's start (it cannot get there
                # before ready_timeout_s), so they start and are heard; playback then jumps it forward
                if self._hold_ns is None:
                    self._hold_ns = self._first_time() - int(self.params.ready_timeout_s * 1e9) - 1
                    self._hold_wall = time.monotonic()
                self._tick_clock(self._hold_ns + int((time.monotonic() - self._hold_wall) * 1e9))
            self.spin_once(0.02)

    def _topic(self, topic: str) -> str:
        topic = self.params.remap.get(topic, topic)
        return self.remap.get(topic, topic)

    def _send(self, m: BagMessage) -> None:
        header = Header(type=m.type, seq=m.seq, stamp=time.time_ns(), node=m.node, latched=m.latched)
        self.publish_raw(self._topic(m.topic), header, m.payload, m.blobs, latched=m.latched)
        self.played += 1

    def _first_time(self) -> int:
        """Where playback starts in recorded time (the first message's time on the timeline, plus the offset)."""
        for m in iter_bag(self.paths, on_damage=lambda text: None):
            if self.params.timeline == "log":
                return m.log_time + int(self.params.start_offset_s * 1e9)
            if self._filter(m.topic):
                return m.publish_time + int(self.params.start_offset_s * 1e9)
        return time.time_ns()

    def _tick_clock(self, sim_ns: int) -> None:
        if self._clock_pub is not None:
            self._clock_pub.publish(ClockTick(sim_ns=sim_ns))

    def _wait_until(self, due: float, t0: float, start_ns: int) -> bool:
        """Wait for perf_counter() >= due, servicing the node and the clock; False when asked to stop.

        Long waits poll the node's sockets (ZeroMQ polls in whole ms); the last few ms are slept with
        ``time.sleep`` (us resolution) and only the final ``_SPIN_S`` is spent spinning. Spinning longer looks
        more precise but keeps the process on the CPU all the time at high message rates, and on a busy machine
        the scheduler then preempts it for whole time slices (measured: 4-8 ms stalls at 1 kHz on 2 cores).
        """
        rate = self.params.rate
        period = 1.0 / self.params.clock_hz
        while True:
            now = time.perf_counter()
            if self._clock_pub is not None and now >= self._next_tick:
                self._tick_clock(start_ns + int((now - t0) * rate * 1e9))
                self._next_tick = max(self._next_tick + period, now)
            remaining = due - now
            if remaining <= 0:
                return True
            if self.is_shutdown:
                return False
            if self._clock_pub is not None:
                remaining = min(remaining, max(0.0, self._next_tick - now) + _SPIN_S)
            if remaining > _POLL_S:
                self.spin_once(min(remaining - _POLL_S, 0.1))
            elif remaining > _SPIN_S:
                if now - self._serviced > 0.01:
                    self._serviced = now
                    self.spin_once(0.0)  # heartbeats and incoming messages, without blocking
                    continue
                time.sleep(remaining - _SPIN_S)

    # -- playing -----------------------------------------------------------------------------------------
    def _play_pass(self) -> bool:
        """Play the recording once; False when interrupted by a shutdown request."""
        offset_ns = int(self.params.start_offset_s * 1e9)
        rate = self.params.rate
        start_ns: int | None = None  # recorded time that t0 stands for: the first message + the offset
        t0 = 0.0
        selected = 0
        held: dict[tuple[str, str], BagMessage] = {}  # latched messages before the start offset
        last_latched: dict[tuple[str, str], int] = {}
        by_stamp = self.params.timeline == "publish"
        last_t = 0
        for m in iter_bag(self.paths, on_damage=self.log.warning):
            wanted = self._filter(m.topic)
            if by_stamp and not wanted:
                continue  # other publishers' stamps may be on another clock (the wall's, in a sim graph)
            t = last_t = max(last_t, m.publish_time) if by_stamp else m.log_time
            if start_ns is None:
                start_ns = t + offset_ns
            if t < start_ns:
                if wanted and m.latched:
                    held[(m.topic, m.node)] = m
                continue
            if t0 == 0.0:
                t0 = time.perf_counter()
                self._next_tick = t0
                self._tick_clock(start_ns)
                for h in held.values():
                    self._send(h)
                    last_latched[(h.topic, h.node)] = h.seq
                held.clear()
            if not wanted:
                continue
            selected += 1
            if m.latched:
                key = (m.topic, m.node)
                if last_latched.get(key) == m.seq:
                    continue  # the copy that opens the next piece of a split recording
                last_latched[key] = m.seq
            due = t0 + (t - start_ns) / 1e9 / rate
            if not self._wait_until(due, t0, start_ns):
                return False
            self._send(m)
            self.late_max_s = max(self.late_max_s, time.perf_counter() - due)
        for h in held.values():  # the offset was past the last message: still deliver the latched state
            self._send(h)
        if not selected and not held:
            self.log.warning("nothing to play in %s (no message matches the topic filter%s)",
                             ", ".join(map(str, self.paths)), " after the start offset" if offset_ns else "")
        return True

    def _go_realtime(self) -> None:
        try:
            param = os.sched_param(10)
            for tid in os.listdir("/proc/self/task"):  # every thread: the ZeroMQ I/O thread does the sending
                os.sched_setscheduler(int(tid), os.SCHED_FIFO, param)
            self.log.info("real-time scheduling (SCHED_FIFO 10)")
        except (OSError, AttributeError) as exc:
            self.log.warning("real-time scheduling not permitted (%s): playing with normal priority", exc)

    def spin(self) -> None:
        """Play (and loop) until done or stopped; then exit, or keep the node alive if exit_when_done is off."""
        if self.params.realtime:
            self._go_realtime()
        self._wait_ready()
        t = self.transport
        # the graph's nodes (they heartbeat: tools do not) whose subscriptions were live before the first message
        ready = {probe.rpartition("/")[0] for probe in t.joins_heard} if isinstance(t, ZmqTransport) else set()
        self._downstream = (set(self.params.wait_for) | (ready & self._beats.keys())) - {self.name}
        started = time.monotonic()
        while not self.is_shutdown:
            if not self._play_pass():
                break
            self.passes += 1
            if not self.params.loop:
                break
        if self.is_shutdown:
            return
        self.log.info("played %d messages from %s in %.2f s (%d pass%s)", self.played,
                      ", ".join(map(str, self.paths)), time.monotonic() - started, self.passes,
                      "" if self.passes == 1 else "es")
        if self.params.exit_when_done:
            if not self._downstream:
                end = time.monotonic() + self.params.exit_delay_s
                while not self.is_shutdown and (left := end - time.monotonic()) > 0:
                    self.spin_once(min(left, 0.1))
            drained = self._drain()
            if not self.is_shutdown:
                self.request_shutdown(0 if drained else 1)
            return
        super().spin()

    def _behind(self) -> dict[str, tuple[str, int, int]]:
        """Downstream node -> (a topic, messages it took in, messages played there) where it has not taken in all
        that was played on a topic it subscribes to (by its latest heartbeat; not heard at all: topic "")."""
        out: dict[str, tuple[str, int, int]] = {}
        for node in sorted(self._downstream):
            hb = self._beats.get(node)
            if hb is None:
                out[node] = ("", 0, 0)
                continue
            exact = hb.subscribes.keys()
            prefixes = [t[:-1] for t in exact if t.endswith("*")]
            for topic, n in self._inventory.raw_sent.items():
                if topic in exact or any(topic.startswith(p) for p in prefixes):
                    c = hb.counters.get(topic)
                    got = c.received + c.decode_errors if c is not None else 0
                    if got < n:
                        out[node] = (topic, got, n)
                        break
        return out

    def _drain(self) -> bool:
        """Wait until the downstream nodes have taken in what was played (their heartbeats' counters), while they
        make progress; False (after a warning naming what was lost) when one stopped short of it."""
        last: dict[str, tuple[str, int, int]] | None = None
        deadline = 0.0
        while not self.is_shutdown:
            behind = self._behind()
            if not behind:
                return True
            now = time.monotonic()
            if behind != last:
                last, deadline = behind, now + self.params.drain_timeout_s
            elif now > deadline:
                for node, (topic, got, n) in behind.items():
                    if topic:
                        self.log.warning("%s took in %d of the %d messages played on %s: %d lost", node, got, n,
                                         topic, n - got)
                    else:
                        self.log.warning("%s not heard since the replay started: whether it got the replay is "
                                         "unknown", node)
                return False
            self.spin_once(0.05)
        return True
