"""nodes.drivers.native_stderr: what native code writes on fd 2 during a failing call goes into the driver's one-line
error; during a call that succeeds it is passed on, nothing lost."""

from __future__ import annotations

import os

import pytest

from nodes.drivers.native_stderr import native_stderr


def test_a_failure_keeps_the_text_and_a_success_passes_it_on(capfd: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(RuntimeError), native_stderr() as said:
        os.write(2, b"connect: Connection refused\n")
        raise RuntimeError("could not connect")
    assert said == ["connect: Connection refused"] and capfd.readouterr().err == ""
    with native_stderr() as said:
        os.write(2, b"ur_rtde: connected\n")
    assert said == ["ur_rtde: connected"] and capfd.readouterr().err == "ur_rtde: connected\n"
