"""How the UR driver (nodes.drivers.robot_urrtde) gets its two ur_rtde interfaces: :class:`RtdeInterfaces` is what makes
them, :class:`UrRtde` ur_rtde's own (the default); emulators.ur.local's stand-ins run an emulated controller in process
on the node's clock."""

from __future__ import annotations

from typing import Any, Protocol

from nodes.drivers.robot import RobotConnectionError

__all__ = ["RtdeInterfaces", "UrRtde"]


class RtdeInterfaces(Protocol):
    """What makes ur_rtde's two interfaces (or stand-ins answering the same methods)."""

    threaded: bool
    """Whether the interfaces move on threads of their own in wall time (ur_rtde's receive stream), so the driver
    polls them between its caller's calls from a monitor thread; False: they move only when called."""

    def receive(self, host: str, frequency_hz: float, fields: list[str]) -> Any:
        """rtde_receive.RTDEReceiveInterface(host, frequency_hz, fields); RuntimeError if unreachable."""
        ...

    def control(self, host: str, frequency_hz: float) -> Any:
        """rtde_control.RTDEControlInterface(host, frequency_hz); RuntimeError if it cannot start its script."""
        ...


class UrRtde:
    """ur_rtde's own interfaces (imported at the first connection: a project dependency, with a clear error)."""

    threaded = True

    @staticmethod
    def _modules() -> tuple[Any, Any]:
        try:
            import rtde_control
            import rtde_receive
        except ImportError as e:  # pragma: no cover - ur_rtde is a project dependency
            raise RobotConnectionError(f"ur_rtde is not installed ({e}); pip install ur-rtde") from e
        return rtde_control, rtde_receive

    def receive(self, host: str, frequency_hz: float, fields: list[str]) -> Any:
        return self._modules()[1].RTDEReceiveInterface(host, frequency_hz, fields)

    def control(self, host: str, frequency_hz: float) -> Any:
        return self._modules()[0].RTDEControlInterface(host, frequency_hz)
