"""A launch file's ``prepare`` commands: run in order before any node builds, the first that fails ends the launch."""

from __future__ import annotations

import os
import subprocess
import sys

from palpa.errors import LaunchError
from palpa.launch.output import Screen
from palpa.launch.plan import LaunchPlan

__all__ = ["run_prepare"]


def run_prepare(plan: LaunchPlan, screen: Screen) -> None:
    """Run ``plan.prepare`` (``python`` meaning this interpreter, the file's ``python_path`` first on PYTHONPATH);
    a :class:`LaunchError` with the command and the last lines it printed for the first that fails."""
    env = dict(os.environ)
    if plan.python_path:
        env["PYTHONPATH"] = os.pathsep.join([*plan.python_path, *filter(None, [env.get("PYTHONPATH")])])
    for argv in plan.prepare:
        cmd = [sys.executable, *argv[1:]] if argv[0] == "python" else list(argv)
        screen.say(f"prepare: {' '.join(argv)}")
        try:
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise LaunchError(f"prepare: {' '.join(argv)}: {exc}") from None
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-5:]
            raise LaunchError(f"prepare: {' '.join(argv)} exited {done.returncode}: {' / '.join(tail)}")
