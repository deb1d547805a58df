"""An unreachable robot (issue 39): the scanner on the ur_rtde driver with nothing listening at its host ends with
one line naming the host, not a traceback."""

from __future__ import annotations

import pytest

from emulators.ur.process import UrEmulatorProcess
from palpa.cli.main import main
from palpa.net.address import BusAddress

pytestmark = pytest.mark.system


def test_an_unreachable_robot_is_one_line_naming_the_host(ipc_bus: BusAddress,
                                                          capfd: pytest.CaptureFixture[str]) -> None:
    nobody = UrEmulatorProcess.on_random_loopback().host  # not started: nothing listens there, refused at once
    code = main(["run", "nodes.scanner.robot_scanner:RobotScanner", "-p", "driver=ur_rtde", "-p", f"robot_host={nobody}",
                 "-p", "autostart=false", "--bus", str(ipc_bus)])
    err = capfd.readouterr().err  # the file descriptor: what the C++ library writes too
    assert code == 2, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"cannot reach the UR controller at {nobody}" in err and err.startswith("nodes.scanner.robot_scanner:")
