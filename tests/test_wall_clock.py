"""The wall-clock census: every wait and deadline of the product reads the node's clock (palpa.timing.clock), except
in the places listed here, each with why. A wait or a decision on the wall clock fires early when the machine is
busy and the node runs on simulated time."""

from __future__ import annotations

import ast
from collections.abc import Mapping
from pathlib import Path

import pytest

from tests import test_architecture as arch

PRODUCT = ("palpa", "nodes", "models", "messages", "devices", "emulators", "tools", "yamlstruct")
WALL_CLOCK = {"monotonic", "monotonic_ns", "time", "time_ns", "sleep", "perf_counter", "perf_counter_ns"}
WALL_DATES = {"now", "utcnow", "today"}


def _scopes(tree: ast.AST) -> dict[ast.AST, str]:
    """Every node of ``tree`` mapped to the dotted name of the def/class it sits in ("" at module level)."""
    where: dict[ast.AST, str] = {}

    def visit(node: ast.AST, scope: str) -> None:
        for child in ast.iter_child_nodes(node):
            inner = scope
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                inner = f"{scope}.{child.name}" if scope else child.name
            where[child] = inner
            visit(child, inner)

    visit(tree, "")
    return where


def _wall_clock_use(node: ast.AST, time_names: set[str]) -> str | None:
    """What ``node`` reads of the wall clock, if anything: a ``time`` function (called or handed on as a clock),
    one imported from ``time``, today's date, or a blocking wait bounded by a timeout."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in time_names \
            and node.attr in WALL_CLOCK:
        return f"time.{node.attr}"
    if isinstance(node, ast.ImportFrom) and node.module == "time":
        names = sorted(a.name for a in node.names if a.name in WALL_CLOCK)
        return f"from time import {', '.join(names)}" if names else None
    if isinstance(node, ast.Attribute) and node.attr in WALL_DATES and \
            ast.unparse(node.value) in ("datetime", "date", "datetime.datetime", "datetime.date"):
        return f"{ast.unparse(node.value)}.{node.attr}"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        timeout = any(k.arg == "timeout" for k in node.keywords)
        if node.func.attr == "wait" and (node.args or timeout):
            return f"{ast.unparse(node.func)}(timeout)"
        if node.func.attr == "get" and timeout:
            return f"{ast.unparse(node.func)}(timeout=)"
    return None


def wall_clock_reads(packages: tuple[str, ...]) -> dict[str, list[str]]:
    """Every read of the wall clock in ``packages``, as ``{"module:Scope.name": ["line: what", ...]}``."""
    found: dict[str, list[str]] = {}
    for name, path in arch.source_modules(packages).items():
        tree = ast.parse(path.read_text(), str(path))
        time_names = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.Import)
                      for a in n.names if a.name == "time"}
        scopes = _scopes(tree)
        for node in ast.walk(tree):
            what = _wall_clock_use(node, time_names)
            if what is not None:
                scope = scopes.get(node, "")
                found.setdefault(f"{name}:{scope}" if scope else name, []).append(f"{node.lineno}: {what}")
    return {k: sorted(v, key=lambda s: int(s.split(":")[0])) for k, v in found.items()}


# The places that read the wall clock on purpose, each with why. A key is a module, or a module and the def or class
# (everything inside it) that does. Everything else waits and decides on its node's clock (palpa.timing.clock.Deadline,
# a node's timers, or a clock handed to a driver).
WALL_CLOCK_ALLOWED = {
    # the clock implementations
    "palpa.timing.clock": "the clocks themselves: SystemClock is the wall clock; Deadline measures a SystemClock "
                          "on the monotonic clock behind it",
    "palpa.timing.simclock": "the lockstep clock node: it paces simulated time against the wall and times out "
                             "nodes that stop answering (a clock implementation)",
    "palpa.record.player": "palpa play is a clock implementation: it replays recorded time at a wall-clock rate "
                           "(and publishes it as the simulation clock), waiting wall time for its listeners",
    "palpa.timing.compose:Composition.__init__": "the composition's simulated time starts at the wall clock's "
                                                 "whole second (an origin, not a wait)",
    "palpa.timing.compose:Composition._take_outside": "rate-limits a syscall: how often a busy composition looks "
                                                      "at the real bus through its bridge",
    "palpa.timing.compose:main": "reports how many times faster than real time a composition ran",
    "nodes.mapping.map_output:_end": "a helper process's exit lives in wall time: the wait bounds it, then kills it "
                                     "(the map node draws the picture itself when the helper fails)",
    "palpa.node.node_time:SimTime.await_first_tick": "before the first tick simulated time does not exist: only "
                                                     "wall time can bound the wait for it",
    "palpa.node.node_time:SimTime.on_clock": "the frozen-time watchdog notes when a tick came, in wall time",
    "palpa.node.node_time:SimTime.on_instant": "the frozen-time watchdog notes when time moved, in wall time",
    "palpa.node.node_time:SimTime.check_alive": "the frozen-time watchdog: when simulated time stops, only the "
                                                "wall clock can tell",
    # sockets, processes, files and the people reading them live in wall time; none of these is a decision of a
    # node's logic
    "palpa.node.presence:confirm_subscriptions": "ZeroMQ subscriptions travel through the proxy in wall time, and "
                                                 "a lockstep clock holds simulated time until the node is ready: "
                                                 "JOIN_TIMEOUT_S on the node's clock would never pass",
    "palpa.node.presence:Heartbeats": "heartbeats are wall-clock liveness for launchers and `palpa node list`, "
                                      "whatever the node's clock (a paused replay's node is alive)",
    "palpa.node.receive:Receiver.count_error": "rate-limits a log line for the human reading it",
    "palpa.node.receive:Receiver._handle": "a raw message's recv_ns is the MCAP log time a recorder writes: when "
                                           "the host received it, on its wall clock (a record, not a decision)",
    "palpa.lograte": "rate-limits log lines (what a peer can make happen at will) for the human reading them",
    "palpa.net.direct:DirectSocket.drain": "stamps the transport's own reach answers (no node, no node clock)",
    "palpa.net.transport:ZmqTransport._busy_wait": "a busy-poll timeout bounds a socket read, not a decision",
    "palpa.net.transport:ZmqTransport._wait_fine": "a sub-ms poll timeout bounds a socket read, not a decision",
    "palpa.net.transport:ZmqTransport._await_proxy": "the proxy's handshake is a socket's, in wall time",
    "palpa.net.handshake:HandshakeWatch": "waits for and retries a CURVE handshake with the proxy: sockets",
    "palpa.launch": "the launcher supervises processes, which live in wall time: exit waits, restart back-off, "
                    "the stop grace, the console's time of day",
    "palpa.cli": "command-line tools talk to a user in wall time (echo/hz windows, --timeout, a unique tool "
                 "node name) and say so",
    "palpa.viz.server": "the websocket viewer refreshes a browser in wall time",
    "palpa.record.recorder:Recorder.setup": "a recording's start time is wall-clock metadata of the file",
    "palpa.record.recorder:Recorder._open_file": "a file's open time is wall-clock metadata of the file",
    "palpa.record.recorder:Recorder.spin": "after stop, drains what its sockets already hold, bounded in wall "
                                           "time (a simulated clock may have stopped with the graph)",
    "tools.evaluate": "reports the wall time a run took, to a user",
    # drivers: hardware lives in wall time; what a node decides about it reads the clock the node hands in
    "nodes.drivers.host_clock": "the clock of a driver used without a node (every node hands in its own)",
    "nodes.drivers.camera:OpenCVSource._run": "the capture thread of a camera (or of a video paced as one): frames "
                                              "come in wall time, and a thread blocks in wall time between them",
    "nodes.drivers.camera:SimSource.read": "the realtime pacing its docstring reserves for a wall clock",
    "nodes.drivers.fibre_serial:SerialFibreDriver._run": "the serial reader thread's reconnect back-off: a port",
    "nodes.drivers.robot_urrtde:URRtdeDriver._monitor_loop": "paces the thread that polls the controller",
    "nodes.drivers.robot_urrtde:URRtdeDriver._kick": "the controller times the RTDE watchdog on its own wall "
                                                     "clock: the kicks that feed it, and the gaps between them, too",
    "nodes.drivers.robot_urrtde:URRtdeDriver._set_watchdog": "arms the RTDE watchdog (see _kick)",
    "nodes.drivers.robot_urrtde:URRtdeDriver._stop_cause": "tells a starved RTDE watchdog (see _kick)",
    # emulators stand in for hardware in another thread or process, which lives in wall time
    "emulators.alicat": "an emulated device (its default clock when a test hands it none)",
    "emulators.fibre_daq": "an emulated device streams on its own wall clock, as the DAQ does",
    "emulators.pty_device": "the pseudo-terminal's reader thread and unplug wait",
    "emulators.ur.server": "the UR emulator serves ur_rtde over TCP in wall time (the system tier); its steppable "
                           "core, emulators.ur.stepper, runs on the clock it is given (the monotonic one here)",
    "emulators.ur.process": "starts, waits for and stops an emulator process",
    "emulators.ur.__main__": "palpa-urfake's main thread waits for a signal",
}


def _listed(key: str, allowed: Mapping[str, str]) -> bool:
    return any(key == a or key.startswith((a + ".", a + ":")) for a in allowed)


def test_product_code_reads_the_wall_clock_only_where_listed() -> None:
    """A wait or a decision on the wall clock fires early when the machine is busy and the node runs on simulated
    time; product code reads its node's clock (palpa.timing.clock.Deadline) except in the listed places."""
    found = wall_clock_reads(PRODUCT)
    assert {k: v for k, v in found.items() if not _listed(k, WALL_CLOCK_ALLOWED)} == {}


def test_every_listed_wall_clock_place_still_reads_it() -> None:
    """The list shrinks with the code: a place that no longer reads the wall clock leaves it."""
    found = wall_clock_reads(PRODUCT)
    assert [a for a in WALL_CLOCK_ALLOWED if not any(_listed(k, {a: ""}) for k in found)] == []


def test_the_wall_clock_census_sees_each_kind_of_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pkg = tmp_path / "fakepkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "import time as t\nimport queue\nfrom time import monotonic, strftime\nfrom datetime import datetime\n"
        "class A:\n    def f(self, ev, q, clock=t.time_ns):\n        t.sleep(0.1)\n        ev.wait(0.5)\n"
        "        q.get(timeout=1)\n        return datetime.now(), ev.wait(), q.get(), ', '.join([strftime('%H')])\n")
    monkeypatch.setattr(arch, "ROOT", tmp_path)
    assert wall_clock_reads(("fakepkg",)) == {
        "fakepkg": ["3: from time import monotonic"],
        "fakepkg:A.f": ["6: time.time_ns", "7: time.sleep", "8: ev.wait(timeout)", "9: q.get(timeout=)",
                        "10: datetime.now"]}
    assert _listed("fakepkg:A.f", {"fakepkg:A": ""}) and not _listed("fakepkg:A.f", {"fakepkg:A.g": ""})
