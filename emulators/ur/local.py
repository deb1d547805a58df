"""The emulated UR controller in process: stand-ins for ur_rtde's two interfaces, stepped on the caller's clock.

``URRtdeDriver(host, interfaces=hosts, clock=...)`` then drives :class:`~emulators.ur.controller.UrController` without
a socket or a thread: each call of a stand-in first runs the controller's 2 ms cycles due by the clock
(:class:`~emulators.ur.stepper.ControllerClock`), so that the driver, the graph around it and the emulated arm share
one (simulated) time and a test of them is deterministic. What ur_rtde does over TCP is done here on the registers
the control script reads (emulators.ur.script): a command waits for the script to be ready, is written, and is
cleared once the script says it is done; a path is injected into a freshly uploaded script, as ur_rtde's moveL(path)
does. Those waits are on the controller: a blocking call runs the controller's cycles until it answers (a few of
them), as a real call waits for the controller while the caller's clock moves on; here the caller's clock cannot
move within the call, so the controller leads it by those cycles until it catches up.

The real protocol (ur_rtde over TCP to emulators.ur.server) is tested in the system tier; this is what lets the
in-process tier run the driver and the scanner against the same controller. Hosts are names in :data:`hosts`, an
in-process network (like the in-memory bus): a host nobody serves refuses the connection, as ur_rtde says it.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from emulators.ur.controller import (
    ROBOT_BIT_PROGRAM_RUNNING,
    SAFETY_BIT_PROTECTIVE_STOP,
    UrController,
)
from emulators.ur.script import (
    CMD_MOVE_PATH,
    CMD_SET_WATCHDOG,
    CMD_STOP_SCRIPT,
    CMD_STOPL,
)
from emulators.ur.stepper import ControllerClock
from models.arm import TICK_S

__all__ = ["AsyncStatus", "LocalControl", "LocalHosts", "LocalReceive", "LocalUr", "hosts"]

_READY, _DONE = 1, 2  # output_int_register_0: the script's answers
_ANSWER_TICKS = round(3.0 / TICK_S)
"""The most cycles a command waits for the script's answer (ur_rtde's UR_GET_READY_TIMEOUT, 3 s) before it fails."""
_NO_CATCH_UP_LIMIT = 1 << 62
"""An in-process controller never lags its clock: it runs every cycle due, however late it is asked."""


class AsyncStatus:
    """ur_rtde's AsyncOperationStatus over the script's progress register (output_int_register_2): bit 15 says an
    operation runs, bits 0-14 its progress (the waypoint reached), the rest count changes."""

    def __init__(self, value: int) -> None:
        self._value = value

    def value(self) -> int:
        return self._value

    def isAsyncOperationRunning(self) -> bool:  # noqa: N802 - ur_rtde's names
        return bool(self._value & 0x8000)

    def progress(self) -> int:
        return self._value & 0x7FFF if self.isAsyncOperationRunning() else -1


class LocalUr:
    """One emulated controller on a clock (ns): every stand-in call runs it up to the clock's now first.

    ``connected`` is the link: an injected drop (``FaultPlan.drop_at_s``) cuts it for every interface made before.
    """

    def __init__(self, controller: UrController, clock: Callable[[], int]) -> None:
        self.controller = controller
        self.stepper = ControllerClock(controller, clock, max_catchup=_NO_CATCH_UP_LIMIT)
        self.link = 0
        """Bumped by a drop: an interface made on an older link is disconnected."""
        self.refuse_until = 0
        """The controller's tick until which it refuses connections (after a drop)."""
        self.lock = threading.RLock()
        controller.on_drop = self._drop

    def sync(self) -> None:
        """Run the controller's cycles due by the clock."""
        with self.lock:
            self.stepper.step()

    def run_until(self, done: Callable[[], bool], what: str) -> None:
        """Run cycles ahead of the clock until ``done()`` (a blocking ur_rtde call waiting on the controller);
        RuntimeError, as ur_rtde raises, if the script has not answered within its timeout."""
        with self.lock:
            self.sync()
            if self.stepper.run_ahead(done, _ANSWER_TICKS) is None:
                raise RuntimeError(f"{what}: the controller did not answer within {_ANSWER_TICKS * TICK_S:g} s")

    def accept(self) -> LocalUr:
        """This controller, for a new connection; RuntimeError (ur_rtde's words) while it refuses them after a
        drop (``FaultPlan.refuse_s``)."""
        self.sync()
        if self.controller.ticks < self.refuse_until:
            raise RuntimeError("connect: Connection refused (the emulated controller refuses connections after a "
                               "drop)")
        return self

    def _drop(self, refuse_s: float) -> None:
        self.link += 1
        self.refuse_until = self.controller.ticks + math.ceil(refuse_s / TICK_S)


class LocalReceive:
    """RTDEReceiveInterface's getters that URRtdeDriver reads, answered from the controller at the clock's now
    (a streaming pause, ``FaultPlan.pause_stream_at_s``, freezes the answers at the last package)."""

    def __init__(self, ur: LocalUr) -> None:
        self._ur, self._link = ur, ur.link
        self._package: dict[str, Any] = {}
        ur.sync()
        self._take()

    def _take(self) -> dict[str, Any]:
        """The controller's outputs now (the caller has synced it), or the last package while streaming pauses."""
        ctl = self._ur.controller
        if ctl.ticks >= ctl.stream_paused_until or not self._package:
            self._package = {n: ctl.output(n) for n in ("timestamp", "actual_TCP_pose", "actual_TCP_speed",
                                                         "actual_TCP_force", "safety_mode", "runtime_state",
                                                         "safety_status_bits")}
        return self._package

    def isConnected(self) -> bool:  # noqa: N802 - ur_rtde's names
        self._ur.sync()
        return self._link == self._ur.link

    def _get(self, name: str) -> Any:
        if not self.isConnected():  # which runs the controller up to now, once for the getter
            raise RuntimeError("RTDE receive: the connection to the controller is lost")
        return self._take()[name]

    def getTimestamp(self) -> float:  # noqa: N802
        return float(self._get("timestamp"))

    def getActualTCPPose(self) -> list[float]:  # noqa: N802
        return list(self._get("actual_TCP_pose"))

    def getActualTCPSpeed(self) -> list[float]:  # noqa: N802
        return list(self._get("actual_TCP_speed"))

    def getActualTCPForce(self) -> list[float]:  # noqa: N802
        return list(self._get("actual_TCP_force"))

    def isProtectiveStopped(self) -> bool:  # noqa: N802
        return bool(int(self._get("safety_status_bits")) & SAFETY_BIT_PROTECTIVE_STOP)

    def isEmergencyStopped(self) -> bool:  # noqa: N802
        return False  # the emulator has no emergency stop button

    def getSafetyMode(self) -> int:  # noqa: N802
        return int(self._get("safety_mode"))

    def getRuntimeState(self) -> int:  # noqa: N802
        return int(self._get("runtime_state"))


class LocalControl:
    """RTDEControlInterface's commands that URRtdeDriver sends, written to the script's registers as ur_rtde writes
    them (no register offset: the lower range). Construction uploads the control script and waits for it to run,
    and fails as ur_rtde does when the controller refuses remote control or is in a protective stop."""

    def __init__(self, ur: LocalUr) -> None:
        self._ur, self._link = ur, ur.link
        ctl = ur.controller
        with ur.lock:
            ur.sync()
            if not ctl.remote_control:
                raise RuntimeError("RTDEControlInterface: the robot is not in remote control")
            self._upload([])

    def _upload(self, path: Sequence[Sequence[float]]) -> None:
        """Upload the control script (with ``path`` injected as movel lines) and wait until it is ready."""
        moves = "".join(f"  movel(p[{', '.join(repr(float(v)) for v in w[:6])}], a={w[7]!r}, v={w[6]!r}, "
                        f"r={w[8]!r})\n" for w in path)
        ctl = self._ur.controller
        ctl.submit_program("def rtde_control():\n  global reg_offset_float = 0\n  global reg_offset_int = 0\n"
                           f"  # inject move path\n{moves}end\n")
        self._ur.run_until(lambda: ctl.program is not None and ctl.out_int[0] == _READY,
                           "waiting for the control script to run")

    def _command(self, cmd: int, doubles: Sequence[float] = (), asynchronous: bool = False) -> bool:
        """Send ``cmd`` as ur_rtde's sendCommand does: wait for ready, write it, wait for done, clear it."""
        ur = self._ur
        ctl = ur.controller
        with ur.lock:
            ur.sync()
            if not self.isProgramRunning():
                return False
            ur.run_until(lambda: ctl.out_int[0] == _READY or ctl.program is None, "waiting for ready")
            names = ["input_int_register_1", *(f"input_double_register_{i}" for i in range(len(doubles)))]
            ctl.write_inputs(names, [1 if asynchronous else 0, *doubles])
            ctl.write_inputs(["input_int_register_0"], [cmd])
            if cmd == CMD_STOP_SCRIPT:
                ur.run_until(lambda: ctl.program is None, "stopping the control script")
                return True
            ur.run_until(lambda: ctl.out_int[0] == _DONE or ctl.program is None, "waiting for done")
            ctl.write_inputs(["input_int_register_0"], [0])
            ur.run_until(lambda: ctl.out_int[0] == _READY or ctl.program is None, "waiting for ready")
            return ctl.program is not None

    def isConnected(self) -> bool:  # noqa: N802 - ur_rtde's names
        self._ur.sync()
        return self._link == self._ur.link

    def isProgramRunning(self) -> bool:  # noqa: N802
        self._ur.sync()
        return self.isConnected() and bool(self._ur.controller.robot_status_bits & ROBOT_BIT_PROGRAM_RUNNING)

    def moveL(self, path: Sequence[Sequence[float]], asynchronous: bool = False) -> bool:  # noqa: N802
        """ur_rtde's moveL(path): a script with the path injected replaces the running one, then the move command."""
        with self._ur.lock:
            if not self.isConnected():
                raise RuntimeError("RTDE control: the connection to the controller is lost")
            self._ur.sync()
            self._upload(path)
            return self._command(CMD_MOVE_PATH, asynchronous=asynchronous)

    def stopL(self, decel: float, asynchronous: bool = False) -> bool:  # noqa: N802
        return self._command(CMD_STOPL, [decel], asynchronous)

    def setWatchdog(self, min_frequency: float) -> bool:  # noqa: N802
        return self._command(CMD_SET_WATCHDOG, [min_frequency])

    def kickWatchdog(self) -> bool:  # noqa: N802
        """Write the watched input (the command register) with no command, as ur_rtde's kick does."""
        ur = self._ur
        with ur.lock:
            ur.sync()
            if self.isConnected():
                ur.controller.write_inputs(["input_int_register_0"], [0])
            return self.isConnected()

    def getAsyncOperationProgressEx(self) -> AsyncStatus:  # noqa: N802
        self._ur.sync()
        return AsyncStatus(self._ur.controller.out_int[2])

    def stopScript(self) -> None:  # noqa: N802
        self._command(CMD_STOP_SCRIPT)


class LocalHosts:
    """An in-process network of emulated controllers by host name, with ur_rtde's two constructors (the
    ``interfaces`` a URRtdeDriver takes): nothing here runs between calls, so the driver polls it itself."""

    threaded = False

    def __init__(self) -> None:
        self._served: dict[str, LocalUr] = {}

    @contextlib.contextmanager
    def serving(self, host: str, ur: LocalUr) -> Iterator[LocalUr]:
        """Serve ``ur`` at ``host`` for the block."""
        if host in self._served:
            raise ValueError(f"{host!r} is already served here")
        self._served[host] = ur
        try:
            yield ur
        finally:
            del self._served[host]

    def _at(self, host: str) -> LocalUr:
        ur = self._served.get(host)
        if ur is None:
            raise RuntimeError(f"connect: Connection refused (no emulated controller at {host!r} in this process)")
        return ur.accept()

    def receive(self, host: str, frequency_hz: float, fields: Sequence[str]) -> LocalReceive:
        return LocalReceive(self._at(host))

    def control(self, host: str, frequency_hz: float) -> LocalControl:
        return LocalControl(self._at(host))


hosts = LocalHosts()
"""The process's in-process network of emulated controllers (``rtde_interfaces: emulators.ur.local:hosts``)."""
