"""Why the UR driver (nodes.drivers.robot_urrtde) could not connect, each as one line a user can act on: a robot
that does not answer (the network, its IP, its power), one still in a protective stop, one that refuses remote
control, or a control script that would not start. ur_rtde raises RuntimeError for all of them (and prints some
of its own words to stderr, which the driver catches): only the text tells them apart. Split from
nodes.drivers.robot_urrtde, which connects.
"""

from __future__ import annotations

from nodes.drivers.robot import RobotConnectionError

__all__ = ["UNREACHABLE", "control_refused", "in_protective_stop", "unreachable"]

UNREACHABLE = ("connection refused", "timeout connecting", "timed out", "no route to host", "network is unreachable",
               "connection reset", "host is unreachable")
"""ur_rtde's words (its RuntimeError, or what it printed) for a controller that does not answer on a port: all it
raises is RuntimeError, so only the text tells an unreachable robot from a refused script."""


def unreachable(host: str, ports: str, why: str, said: list[str]) -> RobotConnectionError:
    """The one-line error of a robot that does not answer at ``host`` on ``ports``, with ur_rtde's own words."""
    why = why + (f" ({said[0]})" if said and said[0] else "")
    return RobotConnectionError(f"cannot reach the UR controller at {host} ({ports}): {why}. "
                                "Check the network, the robot's IP and that it is powered on.")


def in_protective_stop(host: str) -> RobotConnectionError:
    """The error of a robot found in a protective stop on connecting: the driver does not start a script then."""
    return RobotConnectionError(
        f"the UR at {host} is in a protective stop: find the cause, unlock it on the teach pendant "
        "(or dashboard 'unlock protective stop'), then connect again")


def control_refused(host: str, text: str, said: list[str]) -> RobotConnectionError:
    """The error of a control interface ur_rtde could not start at ``host``: its RuntimeError's ``text`` and what it
    printed (``said``) tell an unreachable controller, one in local control, or a script that would not start."""
    if any(word in f"{text} {said[0] if said else ''}".lower() for word in UNREACHABLE):
        return unreachable(host, "control interface: RTDE 30004, dashboard 29999, script 30003", text, said)
    if "remote control" in text.lower():
        return RobotConnectionError(
            f"the UR at {host} refuses remote control ({text}): on the teach pendant enable "
            "Settings > System > Remote Control, then switch the pendant from Local to Remote")
    return RobotConnectionError(f"cannot start ur_rtde's control script on the UR at {host}: {text}")
