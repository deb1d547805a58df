"""The robot scanner's parameters (nodes.scanner.robot_scanner.RobotScanner.Params): a module of their own so that
the scanner's collaborators (its plan, specimen, services and supervision) read them without importing the node."""

from __future__ import annotations

import math
from typing import Literal

import palpa

__all__ = ["ScannerParams"]


class ScannerParams(palpa.Params):
    """The robot scanner's parameters (launch files set them; the safety limits are fixed at launch)."""

    driver: Literal["sim", "ur_rtde"] = "sim"
    mode: Literal["sweep", "indent"] = "sweep"
    region_mm: list[float] = []
    """x0, y0, x1, y1 of the raster in the phantom frame; empty: the geometry's footprint less edge_margin_mm."""
    geometry: str = ""
    """Measured-geometry file (models.geometry): the specimen's footprint and thickness as someone measured them."""
    edge_margin_mm: float = 4.0
    """Default region: the footprint (or the searched extent) less this on every side."""
    search_box_mm: list[float] = []
    """xmin, ymin, zmin, xmax, ymax, zmax: without region_mm, find the specimen in this box: touch down from its
    top towards its floor at a grid of points search_step_mm apart (contact or none, by the touchoff signal);
    the region is the extent of the points that found it less edge_margin_mm, its surface fitted through them."""
    search_step_mm: palpa.Positive = 10.0
    touchoff: Literal["off", "heights", "indenters", "force"] = "off"
    """Find the surface before the raster (nodes/scanner/touchoff.py) by this contact signal; off: flat contact_z_mm."""
    touch_grid: int = 3
    """Touch-off points: a grid x grid lattice over the region (2: corners and centre)."""
    touch_inset_mm: float = 0.0
    """Touch-off points this far inside the region (the air-float probe's SPS ring must lie on the specimen)."""
    table_point_mm: list[float] = []
    """x, y (phantom frame) of bare table beside the specimen: before the touch-off the air-float probe's SPS find
    the table's height there (``touchoff: heights`` only; a real move, so the point must lie inside the workspace box
    and the SPS ring clear of the specimen, or the scanner refuses before any motion), published latched on
    ``scanner/table``: the estimator's ``thickness: probe`` counts from it. Empty: the table is z = 0 of the frame
    (as registered: docs/robot.md)."""
    touch_threshold: float = 0.0
    """Contact threshold (heights, indenters: mm; force: N); 0: the signal's default (9 mm, 0.3 mm, 0.5 N)."""
    search_speed_mm_s: float = 5.0
    search_clearance_mm: float = 8.0
    """Touch-off descents start this far above the thickest measured point (the box's top without geometry)."""
    working_offset_mm: float = 1.0
    """After a touch-off, sweep: the probe face's height above the found surface."""
    follow_gain_per_s: palpa.NonNegative = 10.0
    """Sweep over a found surface with the air-float probe: its heights hold the face's clearance (eq. 2's d_n)
    at working_offset_mm along each line, taking this fraction of the error out per second (0: no following;
    nodes/scanner/surface_follow.py)."""
    follow_step_mm: palpa.Positive = 1.5
    """Following: the lines' waypoints at most this far apart (a correction acts within one step)."""
    follow_max_offset_mm: palpa.SafetyLimit[palpa.Positive] = 2.0
    """Following never moves a line more than this from its plan."""
    max_press_fraction: palpa.SafetyLimit[float] = 0.6
    """After a touch-off, indent: never press deeper than this fraction of the thinnest found point."""
    spacing_mm: palpa.Positive = 2.0
    speed_mm_s: palpa.Positive = 10.0
    """Sweep: speed along a line. Indent: press and lift speed."""
    axis: Literal["x", "y"] = "y"
    """Lines run parallel to this axis (the paper's Fig. 12 scan: y)."""
    sweep_climb_mm: palpa.NonNegative = 0.05
    """``scanner/probe_at``: a sweep whose line rises by more than this over the found surface starts at its lower
    end and climbs; a flatter one starts at the end nearer the arm. The air-float indenter's bore friction holds it
    on the extending side of its play while the layer under it thickens (as it lands), and pushes it to the other
    side while it thins: on the 4-2 mm dome a descending sweep read 9-10 % softer than a climbing one (BENCHMARKS.md,
    "The planner's own false-alarm law"), so a lattice of short sweeps taken both ways made 7 σ bumps on blank maps
    (nodes.scanner.scan_control.sweep_ends). A raster's serpentine lines still alternate (they average out in its
    dense map)."""
    contact_z_mm: float = 5.0
    """Probe face height while sweeping (sweep), or the surface height pressed from (indent)."""
    indent_depth_mm: palpa.Positive = 3.0
    hold_s: palpa.NonNegative = 0.5
    point_spacing_mm: palpa.NonNegative = 0.0
    """Indent mode: spacing of points along a line (0: same as spacing_mm)."""
    approach_clearance_mm: palpa.NonNegative = 5.0
    retract_clearance_mm: palpa.NonNegative = 15.0
    transit_speed_mm_s: palpa.Positive = 40.0
    approach_speed_mm_s: palpa.Positive = 10.0
    accel_mm_s2: palpa.Positive = 500.0
    home_mm: tuple[float, float, float] = (0.0, 0.0, 40.0)
    """Start pose of the simulated arm (phantom frame)."""
    workspace_mm: palpa.SafetyLimit[tuple[float, float, float, float, float, float]] = (
        -10.0, -10.0, 0.5, 70.0, 70.0, 60.0)
    """xmin, ymin, zmin, xmax, ymax, zmax: the arm never leaves this box."""
    max_speed_mm_s: palpa.SafetyLimit[palpa.Positive] = 50.0
    max_accel_mm_s2: palpa.SafetyLimit[palpa.Positive] = 1000.0
    watch_topic: palpa.SafetyLimit[Literal["probe/heights", "camera/indenters", ""]] = "probe/heights"
    """Probe data that must stay fresh while moving ('' disables the watchdog: bench tests only)."""
    watchdog_s: palpa.SafetyLimit[palpa.Positive] = 0.05
    pressure_watchdog_s: palpa.SafetyLimit[palpa.NonNegative] = 0.5
    """Once ``pressure/state`` has been heard, it going quiet this long while moving stops the arm like stale
    probe data (a dead pressure controller means unknown contact force); 0 disables."""
    stale_hold_s: palpa.SafetyLimit[palpa.NonNegative] = 0.0
    """A scan stopped by stale data (either watchdog above) holds, paused, this long for the data to come back,
    then goes on along its line from where it stopped (each hold logged and counted in the final status); still
    stale after it, the scan ends as a fault. 0: it ends at once (a probe fails instead, for its caller to
    retry, whatever this is)."""
    startup_timeout_s: palpa.Positive = 10.0
    """How long to wait for the probe's first data before giving up."""
    pose_rate_hz: palpa.Positive = 250.0
    linger_s: palpa.NonNegative = 0.5
    """After the scan: keep publishing this long so the last samples reach the map, then exit."""
    # drivers
    time_scale: palpa.Positive = 1.0
    """Sim driver: simulated seconds per clock second (use the graph's sim clock instead when you can)."""
    robot_host: str = "127.0.0.1"
    frame_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Phantom frame origin in the robot base frame (mm)."""
    tool_rotvec: tuple[float, float, float] = (0.0, math.pi, 0.0)
    """Fixed tool orientation (rotation vector, rad): probe pointing down."""
    rtde_interfaces: str = ""
    """ur_rtde: ``MODULE:name`` of what makes its two interfaces instead of ur_rtde itself
    (nodes.drivers.rtde_interfaces.RtdeInterfaces); ``emulators.ur.local:hosts`` drives an emulated controller served
    at ``robot_host`` in this process, on the node's clock (the in-process tests). Empty: ur_rtde over TCP."""
    rtde_watchdog_hz: palpa.SafetyLimit[palpa.NonNegative] = 2.0
    """ur_rtde: the controller stops the program (and the arm) when this process has not kicked its RTDE
    watchdog for 1/rtde_watchdog_hz s (a stalled PC or a cut cable); 0: no watchdog."""
    autostart: bool = True
    """Run the raster at start-up (and exit when it is done); false: stay idle and serve probe_at requests."""
    probe_rest_s: palpa.NonNegative = 0.6
    """``scanner/probe_at``: the earliest answer after a probe's path has ended (the rest at its end, and time for
    the estimator's last estimates); the answer also waits, whatever this is, until an estimate measured at or after
    the path's end has arrived (nodes.scanner.scan_control), so a shorter rest loses no estimate, it only stops
    waiting for nothing. An adaptive air-float scan sets 0.1: this rest was a third of each of its sweeps' time."""
