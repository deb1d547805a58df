"""Camera tracker node: the multi-indenter probe's camera -> ``camera/indenters`` (Algorithm 1, models.tracker).

``driver: opencv`` reads a camera (``device: 0`` or ``/dev/video2``), a video file or an image sequence
(``frames/%04d.png``) through OpenCV in a capture thread (nodes/drivers/camera.py); ``driver: sim`` renders the
probe camera from ``robot/pose`` and the phantom (nodes/drivers/camera_sim.py). Both publish:

- ``camera/indenters`` (IndenterDisplacements): every processed frame once the zero reference exists;
- ``camera/status`` (DeviceStatus, latched): each second and on a change of state;
- ``camera/debug`` (ImageInfo + the image as a blob) at ``debug_hz`` when > 0: the frame with the tracking windows.

Displacements are zero-referenced on the first ``zero_frames`` frames in which all markers are seen (the probe
must be off the sample then), or on a stored calibration (``rest_x_px``). Frame stamps: sim frames carry the
node clock's time of the frame; OpenCV frames the host wall clock at grab.
"""

from __future__ import annotations

import json
from typing import Literal

import cv2
import numpy as np

import palpa
from messages import DeviceStatus, ImageInfo, IndenterDisplacements, RobotPose, Text
from messages.probe import DeviceState
from models.camera_render import CameraModel
from models.camera_world import ProbeErrorSpec
from models.kalman import KalmanParams
from models.multi_indenter import PAPER_GEOMETRY, PX_PER_MM, ProbeGeometry
from models.tracker import Calibration, Tracker, TrackerConfig, TrackResult, annotate
from nodes.common import load_probe_calibration, phantom_from_param
from nodes.drivers.camera import CameraError, Frame, FrameSource, OpenCVSource
from nodes.drivers.camera_sim import SimCameraSource

__all__ = ["CameraTracker"]


class CameraTracker(palpa.Node):
    """Reads frames from a camera driver, tracks the four markers and publishes indenter displacements."""

    class Params(palpa.Params):
        driver: Literal["sim", "opencv"] = "sim"
        device: int | str = 0
        """opencv: camera index, device path, video file or image-sequence pattern (``frames/%04d.png``)."""
        pacing: Literal["realtime", "fast", "every"] = "realtime"
        """opencv files: at the file's fps, as fast as decoded (drops), or every frame as fast as tracked."""
        exit_at_end: bool = False
        """opencv files: exit (code 0) when the video or sequence ends."""
        poll_hz: palpa.Positive = 200.0
        """How often the node asks the driver for a new frame."""
        # Algorithm 1
        hsv_lower: tuple[int, int, int] = (40, 100, 50)
        """Inclusive lower HSV bound of the marker colour (OpenCV: H 0..179, S and V 0..255)."""
        hsv_upper: tuple[int, int, int] = (85, 255, 255)
        regions: list[tuple[int, int, int, int]] = []
        """Per marker (indenter order) search region x0, y0, x1, y1 (px); empty: four vertical strips."""
        window_half_px: tuple[int, int] = (24, 18)
        min_area_px: palpa.NonNegative = 40.0
        centroid: Literal["gray", "mask"] = "gray"
        kalman_q: palpa.Positive = 0.09
        kalman_r: palpa.Positive = 4.0
        kalman_p0: palpa.Positive = 6.0
        zero_frames: int = 30
        """Frames averaged for the zero reference (1 = the paper's first frame)."""
        rest_x_px: list[float] = []
        """Stored calibration: marker x (px) at zero displacement; empty: measure it on the first frames."""
        calibration_file: palpa.InputPath = ""
        """A probe calibration (``python -m tools.camera_calibrate``): its per-marker pixel -> mm maps replace
        ``px_per_mm`` and its direction ``direction``. Empty: the nominal scale."""
        px_per_mm: palpa.Positive = PX_PER_MM
        direction: float = 1.0
        debug_hz: palpa.NonNegative = 0.0
        debug_encoding: Literal["png", "jpg", "bgr8"] = "png"
        # sim driver
        phantom: palpa.InputPath = ""
        rate_hz: palpa.Positive = 30.0
        """Sim camera frame rate (the paper's camera: 30 fps)."""
        pan_deg: float = 0.0
        """Sim: inclination of the sample's surface relative to the probe along its x (the paper's θ)."""
        tilt_deg: float = 0.0
        """Sim: inclination along the probe's y (the paper's α)."""
        pixel_noise_px: float = -1.0
        """Sim raw centroid noise σ (px); negative: the phantom's noise.pixel (0.3 px by default)."""
        image_noise_dn: palpa.NonNegative = 2.0
        blur_sigma_px: palpa.NonNegative = 0.7
        drift_amplitude: palpa.NonNegative = 0.08
        soft_spring_n_per_mm: palpa.Positive = 0.05
        hard_spring_n_per_mm: palpa.Positive = 0.25
        seed: int = 0
        """Sim: the seed of the image noise."""
        device_seed: int = 0
        """Sim: which probe (its springs, marker scales, friction and lens are drawn from this seed)."""
        sim_errors: Literal["realistic", "ideal"] = "realistic"
        """Sim: the probe as built (drawn from ``device_seed``), or a perfect one (nominal springs and scale, no
        friction or distortion; unit tests of the estimator's algebra only)."""
        tip_radius_mm: palpa.Positive = 2.0
        """Sim: radius of the indenters' hemispherical tips (tissue phantoms)."""
        tolerance_spread: Literal["normal", "uniform"] = "normal"
        """Sim: how the probe's springs and scales fall in their tolerance bands (models.camera_world)."""

    params: Params

    def setup(self) -> None:
        p = self.params
        self.indenters = self.publisher("camera/indenters", IndenterDisplacements)
        self.status_pub = self.publisher("camera/status", DeviceStatus, latched=True)
        self.debug_pub = self.publisher("camera/debug", ImageInfo) if p.debug_hz > 0 else None
        cal_file = load_probe_calibration(p.calibration_file, self.name) if p.calibration_file else None
        direction = cal_file.direction if cal_file is not None else p.direction
        try:
            config = TrackerConfig(
                hsv_lower=p.hsv_lower, hsv_upper=p.hsv_upper, regions=tuple(p.regions) or None,
                window_half_px=p.window_half_px, min_area_px=p.min_area_px, centroid=p.centroid,
                kalman=KalmanParams(p.kalman_q, p.kalman_r, p.kalman_p0), px_per_mm=p.px_per_mm,
                direction=direction, zero_frames=p.zero_frames,
                scale_poly=cal_file.scale_poly if cal_file is not None else None,
            )
            cal = (Calibration(tuple(p.rest_x_px), p.px_per_mm, direction, config.scale_poly) if p.rest_x_px
                   else None)
            self.tracker = Tracker(config, cal)
        except ValueError as exc:
            raise palpa.ParamError(f"node {self.name!r}: {exc}") from None
        self.sim: SimCameraSource | None = None
        self.driver: FrameSource
        if p.driver == "sim":
            geometry = PAPER_GEOMETRY
            if (p.soft_spring_n_per_mm, p.hard_spring_n_per_mm) != (0.05, 0.25):
                geometry = ProbeGeometry.paper(k_soft_n_per_mm=p.soft_spring_n_per_mm,
                                               k_hard_n_per_mm=p.hard_spring_n_per_mm)
            # With direction -1 the spheres travel towards smaller x: start them at the right of their strips.
            rest = CameraModel().rest_x_px if p.direction > 0 else tuple(160.0 * j + 142.0 for j in range(4))
            camera = CameraModel(noise_dn=p.image_noise_dn, blur_sigma_px=p.blur_sigma_px, rest_x_px=rest,
                                 drift_amplitude=p.drift_amplitude, px_per_mm=p.px_per_mm, direction=p.direction)
            self.sim = SimCameraSource(
                phantom_from_param(p.phantom, self.name), self.clock.now_ns, rate_hz=p.rate_hz,
                pan_deg=p.pan_deg, tilt_deg=p.tilt_deg, camera=camera,
                pixel_noise_px=None if p.pixel_noise_px < 0 else p.pixel_noise_px, geometry=geometry, seed=p.seed,
                errors=None if p.sim_errors == "ideal" else ProbeErrorSpec(spread=p.tolerance_spread), device_seed=p.device_seed, tip_radius_mm=p.tip_radius_mm,
            )
            # The probe as built is the run's truth: published once, latched, so that a recording keeps it.
            truth = json.dumps({"driver": "sim", "sim_errors": p.sim_errors, "device_seed": p.device_seed,
                                "tolerance_spread": p.tolerance_spread, "build": self.sim.build.to_dict()})
            self.publisher("sim/truth/camera", Text, latched=True).publish(Text(stamp_ns=self.clock.now_ns(),
                                                                                text=truth))
            self.log.info("sim probe: %s", truth)
            self.subscribe("robot/pose", self.on_pose)
            self.driver = self.closing(self.sim)
        else:
            try:
                # closed by the node whatever happens next, a failing open() or setup() included
                self.driver = self.closing(OpenCVSource(p.device, pacing=p.pacing))
                self.driver.open()
            except CameraError as exc:
                raise palpa.ParamError(f"node {self.name!r}: device {p.device!r}: {exc}") from None
        if p.driver == "sim":
            self.driver.open()
        self.processed = 0
        self.frames_with_lost_marker = 0
        self._last_state: tuple[bool, str] | None = None
        self._debug_due_ns = 0
        self._read_timeout = 0.02 if p.pacing == "every" and p.driver == "opencv" else 0.0
        self.timer(1.0 / p.poll_hz, self.poll)
        self.timer(1.0, self.publish_status, first_in_s=0.0)

    def on_pose(self, m: RobotPose) -> None:
        if self.sim is not None:
            self.sim.set_pose(m.stamp_ns, m.x_mm, m.y_mm, m.z_mm)

    def poll(self) -> None:
        # Live sources give at most one new frame per call (newest only); "every" replays may give a few.
        for _ in range(8):
            frame = self.driver.read(self._read_timeout)
            if frame is None:
                break
            self.handle(frame)
        info = self.driver.info()
        if self._state() != self._last_state:
            self.publish_status()
        if info.ended and self.params.exit_at_end:
            self.request_shutdown(0)

    def handle(self, frame: Frame) -> None:
        """Track one frame and publish its displacements (once zeroed) and, when due, the debug image."""
        r = self.tracker.process(frame.image)
        self.processed += 1
        if not r.valid.all():
            self.frames_with_lost_marker += 1
        if r.zeroed:
            y = self.tracker.last_y_px
            self.indenters.publish(IndenterDisplacements(
                stamp_ns=frame.stamp_ns, frame_seq=frame.seq,
                displacement_mm=_quad(r.displacement_mm), centroid_x_px=_quad(r.filtered_x_px),
                centroid_y_px=_quad(y), valid=(bool(r.valid[0]), bool(r.valid[1]), bool(r.valid[2]), bool(r.valid[3])),
            ))
        if self.debug_pub is not None and self.clock.now_ns() >= self._debug_due_ns:
            self._debug_due_ns = self.clock.now_ns() + int(1e9 / self.params.debug_hz)
            self.publish_debug(frame, r)

    def publish_debug(self, frame: Frame, r: TrackResult) -> None:
        if self.debug_pub is None:
            return
        image = annotate(frame.image, r, self.tracker.windows)
        enc = self.params.debug_encoding
        if enc == "bgr8":
            blob = np.ascontiguousarray(image).tobytes()
        else:
            ok, buf = cv2.imencode("." + enc, image)
            if not ok:
                self.log.warning("could not encode the debug image as %s", enc)
                return
            blob = buf.tobytes()
        self.debug_pub.publish(ImageInfo(stamp_ns=frame.stamp_ns, width=image.shape[1], height=image.shape[0],
                                         encoding=enc), blobs=[blob])

    def _state(self) -> tuple[bool, DeviceState]:
        info = self.driver.info()
        if info.ended:
            return False, "down"
        if not info.connected:
            return False, "reconnecting" if info.kind == "device" else "down"
        return True, "ok"

    def publish_status(self) -> None:
        info = self.driver.info()
        connected, state = self._state()
        if (connected, state) != self._last_state:
            if connected:
                self.log.info("camera %s up (%s)", info.name, info.kind)
            elif info.ended:
                self.log.info("camera %s: end of video after %d frames", info.name, info.frames)
            elif self._last_state is not None:
                self.log.warning("camera %s %s: %s", info.name, state, info.last_error)
        self._last_state = (connected, state)
        if info.ended:
            message = "end of video"
        elif not connected:
            message = info.last_error
        elif self.tracker.calibration is None:
            message = f"zeroing: {self.tracker.zero_progress}/{self.params.zero_frames} frames with every marker seen"
        else:
            message = ""
        self.status_pub.publish(DeviceStatus(
            stamp_ns=self.clock.now_ns(), device="camera", connected=connected, state=state, message=message,
            counters={"frames": info.frames, "dropped": info.dropped, "processed": self.processed,
                      "frames_with_lost_marker": self.frames_with_lost_marker, "reconnects": info.reconnects},
        ))


def _quad(v: object) -> tuple[float, float, float, float]:
    a = [float(x) for x in np.asarray(v, dtype=np.float64).tolist()]
    if len(a) != 4:
        raise ValueError(f"camera/indenters carries 4 markers, the tracker has {len(a)}")
    return a[0], a[1], a[2], a[3]


if __name__ == "__main__":
    palpa.run_node(CameraTracker)
