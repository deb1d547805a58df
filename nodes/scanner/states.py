"""The robot scanner's states and the one table of the changes between them.

Every change of the scanner's state is an :class:`Event` looked up in :data:`TRANSITIONS` (from-state, event,
to-state) by :class:`ScanStateMachine`; a change the table does not hold is a bug and raises
:class:`IllegalTransition` rather than happening. The tests read the table (tests/test_scanner_states.py): every
state reachable, every state that is not final can end idle, done or in a fault, and e-stop and abort stop the
arm from every state in which it is under way.

The states are finer than the names published on ``robot/scan_status`` (:attr:`State.wire`, the names other nodes
read): a paused scan, a scan held for stale data and a paused probe are all ``paused`` on the wire, but they
resume, abort and supervise differently.
"""

from __future__ import annotations

import enum
from typing import Final

from messages.robot import ScanState

__all__ = ["FINAL", "MOVING", "ON_PATH", "PAUSED", "TRANSITIONS", "Event", "IllegalTransition", "ScanStateMachine",
           "State"]


class State(enum.Enum):
    """What the scanner is doing."""

    PLANNING = "planning"
    """In setup: the plan is made and checked (no change of state can happen before it is over)."""
    WAITING = "waiting"
    """For the probe's first data (a scan, a touch-off or probe requests follow)."""
    IDLE = "idle"
    """Serving ``scanner/probe_at`` requests; the arm at rest."""
    TOUCHING = "touching"
    """The touch-off (or search) finds the specimen's surface."""
    SCANNING = "scanning"
    PROBING = "probing"
    """A probe's path, then the rest until its answer."""
    SCAN_PAUSED = "scan paused"
    """By ``scanner/pause``; ``scanner/resume`` goes on."""
    SCAN_HELD = "scan held"
    """For stale data (``stale_hold_s``): goes on by itself once the data is fresh, a fault if it stays stale."""
    PROBE_PAUSED = "probe paused"
    DONE = "done"
    STOPPED = "stopped"
    FAULT = "fault"
    ESTOP = "estop"

    @property
    def wire(self) -> ScanState:
        """The state's name on ``robot/scan_status``."""
        return _WIRE[self]


_WIRE: Final[dict[State, ScanState]] = {
    State.PLANNING: "planning", State.WAITING: "waiting", State.IDLE: "idle", State.TOUCHING: "touching",
    State.SCANNING: "scanning", State.PROBING: "probing", State.SCAN_PAUSED: "paused", State.SCAN_HELD: "paused",
    State.PROBE_PAUSED: "paused", State.DONE: "done", State.STOPPED: "stopped", State.FAULT: "fault",
    State.ESTOP: "estop",
}


class Event(enum.Enum):
    """Why the scanner's state changes."""

    WAIT = "wait for the probe's data"
    SERVE = "serve scanner/probe_at requests"
    TOUCH_OFF = "find the specimen's surface"
    SCAN = "drive the raster"
    PROBE = "drive a probe's path"
    PAUSE = "scanner/pause"
    HOLD = "hold the scan for stale data"
    RESUME = "go on (scanner/resume, or fresh data after a hold)"
    COMPLETE = "the path is complete (a probe: answered)"
    PROBE_FAILED = "the probe failed (stale data, its path refused by the arm's driver)"
    ABORT = "scanner/abort"
    ARM_STOPPED = "the arm stopped by itself"
    FAULT = "a fault (stale data, the box, the robot, the pressure controller, a path refused)"
    ESTOP = "robot/estop"


S, E = State, Event
TRANSITIONS: Final[tuple[tuple[State, Event, State], ...]] = (
    (S.PLANNING, E.WAIT, S.WAITING),
    (S.PLANNING, E.SERVE, S.IDLE),

    (S.WAITING, E.TOUCH_OFF, S.TOUCHING),
    (S.WAITING, E.SCAN, S.SCANNING),
    (S.WAITING, E.SERVE, S.IDLE),
    (S.WAITING, E.ABORT, S.STOPPED),
    (S.WAITING, E.FAULT, S.FAULT),
    (S.WAITING, E.ESTOP, S.ESTOP),

    (S.IDLE, E.PROBE, S.PROBING),
    (S.IDLE, E.ESTOP, S.ESTOP),

    (S.TOUCHING, E.SCAN, S.SCANNING),
    (S.TOUCHING, E.SERVE, S.IDLE),
    (S.TOUCHING, E.ABORT, S.STOPPED),
    (S.TOUCHING, E.FAULT, S.FAULT),
    (S.TOUCHING, E.ESTOP, S.ESTOP),

    (S.SCANNING, E.PAUSE, S.SCAN_PAUSED),
    (S.SCANNING, E.HOLD, S.SCAN_HELD),
    (S.SCANNING, E.COMPLETE, S.DONE),
    (S.SCANNING, E.ABORT, S.STOPPED),
    (S.SCANNING, E.ARM_STOPPED, S.STOPPED),
    (S.SCANNING, E.FAULT, S.FAULT),
    (S.SCANNING, E.ESTOP, S.ESTOP),

    (S.SCAN_PAUSED, E.RESUME, S.SCANNING),
    (S.SCAN_PAUSED, E.ABORT, S.STOPPED),
    (S.SCAN_PAUSED, E.FAULT, S.FAULT),
    (S.SCAN_PAUSED, E.ESTOP, S.ESTOP),

    (S.SCAN_HELD, E.RESUME, S.SCANNING),
    (S.SCAN_HELD, E.ABORT, S.STOPPED),
    (S.SCAN_HELD, E.FAULT, S.FAULT),
    (S.SCAN_HELD, E.ESTOP, S.ESTOP),

    (S.PROBING, E.PAUSE, S.PROBE_PAUSED),
    (S.PROBING, E.COMPLETE, S.IDLE),
    (S.PROBING, E.PROBE_FAILED, S.IDLE),
    (S.PROBING, E.ABORT, S.IDLE),  # a call fails, not its server: the scanner waits for the next request
    (S.PROBING, E.ARM_STOPPED, S.STOPPED),
    (S.PROBING, E.FAULT, S.FAULT),
    (S.PROBING, E.ESTOP, S.ESTOP),

    (S.PROBE_PAUSED, E.RESUME, S.PROBING),
    (S.PROBE_PAUSED, E.ABORT, S.IDLE),
    (S.PROBE_PAUSED, E.FAULT, S.FAULT),
    (S.PROBE_PAUSED, E.ESTOP, S.ESTOP),

    # done, stopped and fault: the node lingers, then exits. No probe starts meanwhile (the exit would cut it off
    # mid-path: scanner/probe_at refuses it, saying why); an e-stop is always acknowledged and latched (exit 2)
    (S.DONE, E.ESTOP, S.ESTOP),
    (S.STOPPED, E.ESTOP, S.ESTOP),
    (S.FAULT, E.ESTOP, S.ESTOP),
)
del S, E

_NEXT: Final[dict[tuple[State, Event], State]] = {(a, e): b for a, e, b in TRANSITIONS}

FINAL: Final = frozenset({State.DONE, State.STOPPED, State.FAULT, State.ESTOP})
"""Entering one of these, the node ends (after ``linger_s``)."""
MOVING: Final = frozenset({State.TOUCHING, State.SCANNING, State.PROBING})
"""The arm may be under way: the watchdogs, the box and the robot's status are checked."""
ON_PATH: Final = frozenset({State.SCANNING, State.PROBING})
"""The arm follows a planned path, segment by segment."""
PAUSED: Final = frozenset({State.SCAN_PAUSED, State.SCAN_HELD, State.PROBE_PAUSED})


class IllegalTransition(RuntimeError):
    """A change of state that :data:`TRANSITIONS` does not hold: a bug in the scanner."""


class ScanStateMachine:
    """The scanner's current :class:`State`, changed only through :data:`TRANSITIONS`."""

    def __init__(self, state: State = State.PLANNING) -> None:
        self.state = state

    def can(self, event: Event) -> bool:
        """Whether ``event`` changes the current state (a guard: asked before acting on it)."""
        return (self.state, event) in _NEXT

    def fire(self, event: Event) -> State:
        """Change the state by ``event``; raises :class:`IllegalTransition` if the table has no such change."""
        to = _NEXT.get((self.state, event))
        if to is None:
            raise IllegalTransition(f"the scanner cannot {event.value!r} while {self.state.value} "
                                    "(not in nodes.scanner.states.TRANSITIONS): a bug")
        self.state = to
        return to
