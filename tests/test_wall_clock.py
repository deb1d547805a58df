"""The wall-clock census: every wait and deadline of the product reads the node's clock (palpa.timing.clock), except
in the places listed here, each with why. A wait or a decision on the wall clock fires early when the machine is
busy and the node runs on simulated time. The census is an AST walk: it sees a ``time`` function read or handed on,
today's date, and every blocking wait bounded by a timeout (``Event.wait(t)``, ``Thread.join(t)``, ``Queue.get``,
``Popen.wait``/``communicate``, ``subprocess.run(timeout=)``, ZeroMQ ``poll`` and ``RCVTIMEO``/``SNDTIMEO``,
``select``/``selectors``, ``Condition.wait_for``, ``threading.Timer``, ``settimeout``, any ``timeout=``)."""

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


_BOUNDED_BY_ARG = {"wait": 0, "join": 0, "poll": 0, "select": 0, "wait_for": 1, "communicate": 1, "get": 1}
"""Blocking calls whose timeout may come positionally, and where (0-based): ``Event.wait(t)``, ``Popen.wait(t)``,
``Thread.join(t)``, ``zmq`` ``Socket.poll(ms)``/``Poller.poll(ms)``, ``Selector.select(t)``,
``Condition.wait_for(pred, t)``, ``Popen.communicate(input, t)``, ``Queue.get(block, t)``."""
_NOT_A_TIMEOUT = (ast.List, ast.Tuple, ast.Set, ast.ListComp, ast.SetComp, ast.GeneratorExp, ast.Starred,
                  ast.JoinedStr, ast.Dict, ast.DictComp, ast.Lambda)
"""A positional argument of these kinds is not a timeout (``", ".join([...])``, ``sep.join(x for x in ...)``)."""
_SOCKET_TIMEOUTS = {"RCVTIMEO", "SNDTIMEO"}


def _bounded_wait(node: ast.Call) -> str | None:
    """The blocking wait ``node`` bounds by a wall-clock timeout, if it does: any call with a ``timeout=`` keyword
    (``subprocess.run``, ``Popen.communicate``, ``Queue.get``, ``Thread.join``, ``serial.Serial``...), a known
    blocking call with its timeout given positionally (:data:`_BOUNDED_BY_ARG`; a zero timeout does not wait), a
    ``select.select`` with its fourth argument, a ``threading.Timer``, a socket's ``settimeout``, or a ZeroMQ socket's
    receive or send timeout set by ``setsockopt``."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
    shown = ast.unparse(func)
    timeout = next((k.value for k in node.keywords if k.arg == "timeout"), None)
    if timeout is not None:
        return None if isinstance(timeout, ast.Constant) and timeout.value is None else f"{shown}(timeout=)"
    if shown in ("select.select", "select") and len(node.args) == 4:
        return f"{shown}(timeout)"
    if shown == "threading.Timer":
        return f"{shown}(interval)"
    if name == "settimeout" and node.args:
        return f"{shown}(timeout)"
    if name == "setsockopt" and node.args and any(s in ast.unparse(node.args[0]) for s in _SOCKET_TIMEOUTS):
        return f"{shown}({ast.unparse(node.args[0])})"
    at = _BOUNDED_BY_ARG.get(name)
    if at is None or len(node.args) <= at or (name == "get" and len(node.args) != 2):
        return None
    arg = node.args[at]
    if isinstance(arg, _NOT_A_TIMEOUT) or (isinstance(arg, ast.Constant) and arg.value in (0, None)):
        return None
    if name == "join" and isinstance(func, ast.Attribute) and (
            isinstance(func.value, ast.Constant) or ast.unparse(func.value) in ("os.path", "os.pathsep", "os.sep")):
        return None  # str.join, os.path.join
    if name == "get" and not (isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, bool)):
        return None  # dict.get(key, default); Queue.get(True, t) says block
    return f"{shown}(timeout)"


def _wall_clock_use(node: ast.AST, time_names: set[str]) -> str | None:
    """What ``node`` reads of the wall clock, if anything: a ``time`` function (called or handed on as a clock),
    one imported from ``time``, today's date, a blocking wait bounded by a timeout (:func:`_bounded_wait`), or a
    ZeroMQ socket's timeout set as an attribute (``sock.rcvtimeo = 100``)."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in time_names \
            and node.attr in WALL_CLOCK:
        return f"time.{node.attr}"
    if isinstance(node, ast.ImportFrom) and node.module == "time":
        names = sorted(a.name for a in node.names if a.name in WALL_CLOCK)
        return f"from time import {', '.join(names)}" if names else None
    if isinstance(node, ast.Attribute) and node.attr in WALL_DATES and \
            ast.unparse(node.value) in ("datetime", "date", "datetime.datetime", "datetime.date"):
        return f"{ast.unparse(node.value)}.{node.attr}"
    if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and node.attr.upper() in _SOCKET_TIMEOUTS:
        return f"{ast.unparse(node)} ="
    if isinstance(node, ast.Call):
        return _bounded_wait(node)
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
    "palpa.net.bus:Bus._serve_cache": "the cache thread's socket poll wakes every 100 ms to see a stop: sockets",
    "palpa.net.bus:Bus.stop": "bounds the join of the proxy's threads at shutdown (threads over sockets)",
    "palpa.net.exitflush:_flush": "at exit, after every node, bounds ZeroMQ's linger flush of unsent messages",
    "palpa.net.transport:ZmqTransport._accepted": "a socket's grace for the subscriptions the proxy forwards on "
                                                  "attach (the handshake's, like _await_proxy)",
    "palpa.net.transport:ZmqTransport.poll": "blocks on the sockets for as long as the node asks (the node "
                                             "derives that from its clock: Node.spin_once)",
    "palpa.node.node:Node.spin_once": "blocks in its transport until input comes or, on a wall clock, its next "
                                      "timer falls due (a length read on the node's clock; a simulated-clock node "
                                      "waits for input, its tick; the in-memory transport never blocks)",
    "palpa.timing.compose:Composition._wait_outside": "an idle composition (nothing due) waits on its bridge's "
                                                      "socket for input from outside processes; its simulated "
                                                      "time does not move meanwhile",
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
    "tools.evaluate": "reports the wall time a run took, to a user; bounds each run's process",
    "tools.sweep": "a Dask cluster lives in wall time: connecting to its scheduler, the progress thread's end",
    # drivers: hardware lives in wall time; what a node decides about it reads the clock the node hands in
    "nodes.drivers.host_clock": "the clock of a driver used without a node (every node hands in its own)",
    "nodes.drivers.camera:OpenCVSource": "a camera (or a video paced as one) delivers frames in wall time: its "
                                         "capture thread blocks between them, read() waits for the next one, "
                                         "close() bounds the thread's end",
    "nodes.drivers.camera:SimSource.read": "the realtime pacing its docstring reserves for a wall clock",
    "nodes.drivers.fibre_serial:SerialFibreDriver": "a serial port lives in wall time: the port's read timeout, "
                                                    "the wait for a line or a command's reply from the reader "
                                                    "thread, its reconnect back-off, its end at close",
    "nodes.drivers.pressure:AlicatPressureDriver._connect": "the serial port's read and write timeouts bound a "
                                                            "device's answer on the wire",
    "nodes.drivers.robot_urrtde:URRtdeDriver._monitor_loop": "paces the thread that polls the controller",
    "nodes.drivers.robot_urrtde:URRtdeDriver._teardown": "bounds the join of that thread at close",
    "nodes.drivers.robot_urrtde:URRtdeDriver._bounded": "bounds a blocking ur_rtde call: the node's executor is "
                                                        "stuck in it, so the node's clock (simulated or not) cannot "
                                                        "tell how long; only the wall can",
    "nodes.mapping.map_output:PngHelper.render": "the picture helper is a process: its answer is bounded in wall "
                                                 "time, then the node draws the picture itself",
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
    init = (
        "import time as t\nimport queue\nfrom time import monotonic, strftime\nfrom datetime import datetime\n"
        "class A:\n    def f(self, ev, q, clock=t.time_ns):\n        t.sleep(0.1)\n        ev.wait(0.5)\n"
        "        q.get(timeout=1)\n        return datetime.now(), ev.wait(), q.get(), ', '.join([strftime('%H')])\n")
    waits = """\
import os, select, subprocess, threading, zmq, serial
def g(th, proc, sock, poller, sel, cond, q, d, s, parts, sep):
    th.join(5.0)
    proc.communicate(b"x", timeout=3)
    proc.communicate(b"x", 3)
    proc.wait(2)
    subprocess.run(["true"], timeout=9)
    sock.poll(100)
    poller.poll(timeout=50)
    sock.setsockopt(zmq.RCVTIMEO, 100)
    sock.sndtimeo = 50
    sel.select(0.5)
    select.select([sock], [], [], 1.0)
    cond.wait_for(lambda: True, 2.0)
    q.get(True, 2.0)
    threading.Timer(1.0, print)
    s.settimeout(3.0)
    serial.Serial("/dev/x", timeout=0.05)
    return (", ".join(parts), sep.join(p for p in parts), os.path.join("a", "b"), os.pathsep.join([sep]),
            poller.poll(0), sock.poll(), d.get("k", 0), q.get(), cond.wait_for(bool), th.join(),
            serial.Serial("/dev/x", timeout=None), sel.select(), proc.communicate(b"x"))
"""
    arch.plant_package(tmp_path, monkeypatch, {"__init__.py": init, "waits.py": waits})
    assert wall_clock_reads(("fakepkg",)) == {
        "fakepkg": ["3: from time import monotonic"],
        "fakepkg:A.f": ["6: time.time_ns", "7: time.sleep", "8: ev.wait(timeout)", "9: q.get(timeout=)",
                        "10: datetime.now"],
        "fakepkg.waits:g": [
            "3: th.join(timeout)", "4: proc.communicate(timeout=)", "5: proc.communicate(timeout)",
            "6: proc.wait(timeout)", "7: subprocess.run(timeout=)", "8: sock.poll(timeout)",
            "9: poller.poll(timeout=)", "10: sock.setsockopt(zmq.RCVTIMEO)", "11: sock.sndtimeo =",
            "12: sel.select(timeout)", "13: select.select(timeout)", "14: cond.wait_for(timeout)",
            "15: q.get(timeout)", "16: threading.Timer(interval)", "17: s.settimeout(timeout)",
            "18: serial.Serial(timeout=)"]}
    assert _listed("fakepkg:A.f", {"fakepkg:A": ""}) and not _listed("fakepkg:A.f", {"fakepkg:A.g": ""})
