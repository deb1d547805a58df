"""palpa-urfake: run the UR controller emulator (python -m emulators.ur).

Prints one line `READY {"host": ..., "ports": {...}}` on stdout once all ports listen; logs go
to stderr. With --control it also reads commands from stdin, one per line, and answers each
with one JSON line on stdout (this is how tests drive faults in a running emulator):

    state | messages | program | pstop [reason] | unlock | drop [refuse_s] | pause SECONDS |
    remote on|off | faults {"pstop_after_waypoints": 3, ...} | quit

ur_rtde's Python bindings hold the GIL while they block, so the emulator must run in a
different process from any ur_rtde client; see emulators.ur.process for a test wrapper.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

from emulators.clock_file import ClockReader
from emulators.ur.controller import ControllerConfig, FaultPlan, SurfaceLike
from emulators.ur.server import UrEmulator


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{what}: expected {n} comma-separated numbers, got {text!r}")
    return values


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="palpa-urfake", description="Emulated UR e-Series controller for ur_rtde.")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (any 127.x.y.z works)")
    p.add_argument("--dashboard-port", type=int, default=29999)
    p.add_argument("--script-port", type=int, default=30003)
    p.add_argument("--rtde-port", type=int, default=30004)
    p.add_argument("--home", default="300,0,300,0,3.141592653589793,0",
                   help="start pose x,y,z (mm),rx,ry,rz (rad) in the robot base frame")
    p.add_argument("--max-speed", type=float, default=1000.0, help="tool speed cap (mm/s)")
    p.add_argument("--max-accel", type=float, default=5000.0, help="tool acceleration cap (mm/s^2)")
    p.add_argument("--phantom", help="phantom YAML for the contact force (needs models.phantom)")
    p.add_argument("--phantom-origin", default="0,0,0", help="phantom frame origin in the base frame x,y,z (mm)")
    p.add_argument("--force-limit", type=float, default=150.0, help="contact force (N) that protective-stops")
    p.add_argument("--force-noise", type=float, default=1.0,
                   help="TCP force sensor noise, sigma (N) per sample and axis (1: a UR's built-in sensor at its "
                        "best; ~0.01: a wrist F/T sensor)")
    p.add_argument("--force-bias", type=float, default=3.0, help="TCP force offset until zeroed: up to this (N)")
    p.add_argument("--seed", type=int, default=0, help="seed of the force sensor's bias and noise")
    p.add_argument("--local-control", action="store_true", help="robot in local control: refuse remote commands")
    p.add_argument("--unlock-delay", type=float, default=5.0, help="seconds before a protective stop may be unlocked")
    p.add_argument("--pstop-after-waypoints", type=int, help="protective stop after N waypoints of the first motion")
    p.add_argument("--pstop-at", type=float, help="protective stop S seconds into the first motion")
    p.add_argument("--drop-at", type=float, help="drop all connections S seconds into the first motion")
    p.add_argument("--refuse-for", type=float, default=0.0, help="after a drop, refuse connections this long (s)")
    p.add_argument("--pause-stream-at", type=float, help="pause RTDE streaming S seconds into the first motion")
    p.add_argument("--pause-stream-for", type=float, default=1.0, help="length of the streaming pause (s)")
    p.add_argument("--clock-file", help="follow the clock an emulators.clock_file.ClockWriter publishes in this file: "
                        "the arm never moves more than --clock-lead ahead of it, while the controller itself runs on "
                        "(co-simulation with a graph whose clock may fall behind the wall clock); default: the wall "
                        "clock alone")
    p.add_argument("--clock-lead", type=float, default=0.1,
                   help="with --clock-file: how far (s) the arm may move ahead of that clock")
    p.add_argument("--control", action="store_true", help="read control commands from stdin (see module doc)")
    p.add_argument("--quiet", action="store_true", help="do not log controller events to stderr")
    return p


def _faults(args: argparse.Namespace) -> FaultPlan | None:
    plan = FaultPlan(pstop_after_waypoints=args.pstop_after_waypoints, pstop_at_s=args.pstop_at,
                     drop_at_s=args.drop_at, refuse_s=args.refuse_for,
                     pause_stream_at_s=args.pause_stream_at, pause_stream_for_s=args.pause_stream_for)
    armed = (plan.pstop_after_waypoints, plan.pstop_at_s, plan.drop_at_s, plan.pause_stream_at_s)
    return plan if any(v is not None for v in armed) else None


def _command(emu: UrEmulator, line: str) -> dict[str, Any]:
    verb, _, rest = line.strip().partition(" ")
    ctl = emu.controller
    if verb == "state":
        with ctl.lock:
            return {"pose_mm": list(ctl.arm.pose), "speed": list(ctl.arm.tcp_speed), "ticks": ctl.ticks,
                    "arm_steps": ctl.arm_steps, "runtime_state": ctl.runtime_state,
                    "protective_stopped": ctl.protective_stopped,
                    "path_index": ctl.arm.path_index, "moving": ctl.arm.is_moving,
                    "remote_control": ctl.remote_control, "clients": emu.client_count,
                    "force": list(ctl.force)}
    if verb == "program":
        with ctl.lock:
            return {"source": ctl.last_program_source}
    if verb == "messages":
        with ctl.lock:
            return {"messages": list(ctl.messages)}
    if verb == "pstop":
        emu.protective_stop(rest or "injected by command")
    elif verb == "unlock":
        return {"reply": emu.unlock_protective_stop()}
    elif verb == "drop":
        emu.drop_connections(float(rest or 0.0))
    elif verb == "pause":
        emu.pause_streaming(float(rest))
    elif verb == "remote":
        if rest not in ("on", "off"):
            raise ValueError(f"remote: expected 'on' or 'off', got {rest!r}")
        emu.set_remote_control(rest == "on")
    elif verb == "faults":
        emu.arm_faults(FaultPlan(**json.loads(rest)) if rest.strip() else None)
    else:
        raise ValueError(f"unknown command {verb!r}")
    return {"ok": True}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        home = _floats(args.home, 6, "--home")
        origin = _floats(args.phantom_origin, 3, "--phantom-origin")
    except argparse.ArgumentTypeError as e:
        print(f"palpa-urfake: {e}", file=sys.stderr)
        return 2
    phantom: SurfaceLike | None = None
    if args.phantom:
        from models.phantom import load_phantom  # optional: written in another area

        phantom = load_phantom(args.phantom)
    config = ControllerConfig(home_pose=(home[0], home[1], home[2], home[3], home[4], home[5]),
                              max_speed_mm_s=args.max_speed, max_accel_mm_s2=args.max_accel,
                              remote_control=not args.local_control, unlock_delay_s=args.unlock_delay,
                              force_limit_n=args.force_limit, phantom_origin_mm=(origin[0], origin[1], origin[2]),
                              force_noise_n=args.force_noise, force_bias_n=args.force_bias, sensor_seed=args.seed)

    def log(message: str) -> None:
        if not args.quiet:
            print(message, file=sys.stderr, flush=True)

    try:
        clock = ClockReader(args.clock_file) if args.clock_file else None
        emu = UrEmulator(args.host, dashboard_port=args.dashboard_port, script_port=args.script_port,
                         rtde_port=args.rtde_port, config=config, phantom=phantom, faults=_faults(args), log=log,
                         clock=clock, clock_lead_s=args.clock_lead)
        emu.start()
    except (OSError, ValueError) as e:
        print(f"palpa-urfake: {e}", file=sys.stderr)
        return 1
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print("READY " + json.dumps({"host": args.host, "ports": emu.ports}), flush=True)
    try:
        if args.control:
            threading.Thread(target=_control_loop, args=(emu, done), name="urfake-control", daemon=True).start()
        while not done.wait(0.5):
            pass
    finally:
        emu.stop()
    return 0


def _control_loop(emu: UrEmulator, done: threading.Event) -> None:
    for line in sys.stdin:
        if not line.strip():
            continue
        if line.strip() == "quit":
            break
        try:
            answer = _command(emu, line)
        except (ValueError, TypeError) as e:
            answer = {"error": str(e)}
        print(json.dumps(answer), flush=True)
    done.set()  # stdin closed (parent gone) or quit


if __name__ == "__main__":
    sys.exit(main())
