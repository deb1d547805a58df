"""Dashboard server (TCP port 29999): one text command per line, one reply line each.

Replies follow a PolyScope 5.x controller. When the emulated robot is in local control the
commands that would act on the robot are refused, as on a real e-Series teach pendant in
Local mode (the refusal wording is the emulator's).
"""

from __future__ import annotations

from emulators.ur.controller import SAFETY_MODE_PROTECTIVE_STOP, UrController

WELCOME = "Connected: Universal Robots Dashboard Server"
REFUSED = "Command is not allowed due to safety reasons: the robot is in local control"
# commands that act on the robot and therefore need remote control
_ACTING = ("play", "stop", "pause", "load ", "power on", "power off", "brake release",
           "unlock protective stop", "close safety popup", "restart safety", "shutdown")


def reply(ctl: UrController, line: str) -> tuple[str, bool]:
    """Answer one dashboard command; the flag says whether to close the connection after it.
    The caller holds `ctl.lock`."""
    cmd = line.strip()
    low = cmd.lower()
    if low == "quit":
        return "Disconnected", True
    if not ctl.remote_control and any(low == a.strip() or low.startswith(a) for a in _ACTING):
        ctl.log(f"dashboard refused {cmd!r}: local control")
        return REFUSED, False
    v = ctl.config.controller_version
    running = ctl.program is not None
    name = ctl.program.name if ctl.program is not None else "<unnamed>"
    simple = {
        "polyscopeversion": f"URSoftware {v[0]}.{v[1]}.{v[2]}.{v[3]} (Mar 22 2022)",
        "get serial number": ctl.config.serial_number,
        "get robot model": ctl.config.robot_model,
        "is in remote control": "true" if ctl.remote_control else "false",
        "robotmode": "Robotmode: RUNNING",
        "safetymode": "Safetymode: " + ("PROTECTIVE_STOP" if ctl.safety_mode == SAFETY_MODE_PROTECTIVE_STOP else "NORMAL"),
        "safetystatus": "Safetystatus: " + ("PROTECTIVE_STOP" if ctl.safety_mode == SAFETY_MODE_PROTECTIVE_STOP else "NORMAL"),
        "running": f"Program running: {'true' if running else 'false'}",
        "programstate": f"{'PLAYING' if running else 'STOPPED'} {name}",
        "get loaded program": "No program loaded",
        "isprogramsaved": f"true {name}",
        "close popup": "closing popup",
        "close safety popup": "closing safety popup",
        "power on": "Powering on",
        "power off": "Powering off",
        "brake release": "Brake releasing",
        "restart safety": "Restarting safety",
        "shutdown": "Shutting down",
    }
    if low in simple:
        return simple[low], False
    if low == "stop":
        # ur_rtde sends `stop` right after its own stop-script command, when nothing runs any
        # more, and treats anything but "Stopped" as an error: answer "Stopped" either way
        ctl.end_program("stopped from the dashboard")
        return "Stopped", False
    if low == "pause":
        return "Pausing program", False
    if low == "play":
        return "Failed to execute: play", False  # no URP programs in the emulator
    if low == "unlock protective stop":
        return ctl.unlock_protective_stop(), False
    if low.startswith("load "):
        return f"File not found: {cmd[5:]}", False
    if low.startswith("popup "):
        return "showing popup", False
    if low.startswith("addtolog "):
        ctl.log(f"dashboard log: {cmd[9:]}")
        return "Added log message", False
    return f"could not understand: '{cmd}'", False
