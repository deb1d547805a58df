"""A protocol-level emulator of a Universal Robots e-Series controller, for testing ur_rtde.

Layering (imports point down):
    __main__   CLI (palpa-urfake)
    server     sockets + threads: dashboard 29999, script 30003, RTDE 30004
    dashboard  dashboard command replies        rtde  RTDE protocol sessions
    local      ur_rtde's interfaces in process, stepped on the caller's clock (no sockets, no threads)
    stepper    the controller's cycles on a given clock
    controller registers, program, safety, faults, contact force (no sockets)
    script     the emulated ur_rtde control script (no sockets)
    models.arm the Cartesian arm model shared with the simulated robot driver
"""

from emulators.ur.controller import ControllerConfig, FaultPlan, UrController
from emulators.ur.server import UrEmulator

__all__ = ["ControllerConfig", "FaultPlan", "UrController", "UrEmulator"]
