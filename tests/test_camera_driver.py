"""Camera drivers (nodes/drivers/camera.py, camera_sim.py): real OpenCV capture from files, the sim sources."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.camera_render import CameraModel, Renderer
from models.multi_indenter import PAPER_GEOMETRY, forward
from models.phantom import load_phantom
from models.tracker import Tracker, TrackerConfig
from nodes.drivers.camera import (
    CameraError,
    Frame,
    FrameSource,
    OpenCVSource,
    SimSource,
    parse_device,
)
from nodes.drivers.camera_sim import SimCameraSource
from palpa.timing.clock import MockClock
from tests.procs import wait_until

N_FRAMES = 40


def truth_displacements(n: int) -> np.ndarray:
    """A press: markers sweep 0..6 mm at different rates (known for every frame)."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    out: np.ndarray = t * np.array([6.0, 3.8, 5.0, 4.4])
    return out


def write_video(path: Path, fourcc: str, n: int = N_FRAMES, fps: float = 30.0) -> np.ndarray:
    """Rendered frames (no jitter) written with cv2.VideoWriter; returns the drawn centres (n, 4, 2)."""
    renderer = Renderer(CameraModel(jitter_px=0.0), np.random.default_rng(0))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*fourcc), fps, (640, 480))
    assert writer.isOpened(), f"{fourcc} writer unavailable in this OpenCV build"
    centres = []
    for i, d in enumerate(truth_displacements(n)):
        writer.write(renderer.render(d, i / fps))
        centres.append(renderer.last_centres_px.copy())
    writer.release()
    return np.asarray(centres)


@pytest.fixture
def sources() -> Iterator[list[FrameSource]]:
    """Sources opened by a test; all closed at the end whatever happens."""
    opened: list[FrameSource] = []
    try:
        yield opened
    finally:
        for s in opened:
            s.close()


def read_all(src: FrameSource, limit: int = 1000) -> list[Frame]:
    frames = []
    for _ in range(limit):
        f = src.read(2.0)
        if f is None:
            break
        frames.append(f)
    return frames


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
@pytest.mark.parametrize(("fourcc", "ext", "tol_px"), [("FFV1", "avi", 0.05), ("MJPG", "avi", 0.25)])
def test_video_file_through_opencv_source_and_tracker(tmp_path: Path, sources: list[FrameSource], fourcc: str,
                                                      ext: str, tol_px: float) -> None:
    """A recorded experiment replayed frame by frame (pacing "every"): every frame, in order, tracked to the
    positions drawn into it (FFV1 is lossless; MJPG's JPEG blocks cost some accuracy)."""
    path = tmp_path / f"press.{ext}"
    drawn = write_video(path, fourcc)
    src = OpenCVSource(str(path), pacing="every")
    sources.append(src)
    before = time.time_ns()
    src.open()
    frames = read_all(src)
    after = time.time_ns()
    assert [f.seq for f in frames] == list(range(N_FRAMES))
    assert all(before <= f.stamp_ns <= after for f in frames)  # wall clock at grab
    assert all(b.stamp_ns >= a.stamp_ns for a, b in zip(frames, frames[1:], strict=False))
    info = src.info()
    assert info.ended and info.frames == N_FRAMES and info.dropped == 0
    assert (info.width, info.height, info.fps) == (640, 480, 30.0)
    assert src.read(0.0) is None
    tracker = Tracker(TrackerConfig(zero_frames=1))
    raw = np.asarray([tracker.process(f.image).centroids_px for f in frames])
    rms = float(np.sqrt(np.mean((raw - drawn) ** 2)))
    assert rms < tol_px, rms


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
def test_image_sequence_pattern(tmp_path: Path, sources: list[FrameSource]) -> None:
    renderer = Renderer(CameraModel(jitter_px=0.0), np.random.default_rng(1))
    d = truth_displacements(12)
    for i in range(12):
        cv2.imwrite(str(tmp_path / f"frame_{i:04d}.png"), renderer.render(d[i]))
    src = OpenCVSource(str(tmp_path / "frame_%04d.png"), pacing="every")
    sources.append(src)
    assert src.info().kind == "sequence"
    src.open()
    frames = read_all(src)
    assert len(frames) == 12 and src.info().ended
    tracker = Tracker(TrackerConfig(zero_frames=1))
    last = [tracker.process(f.image) for f in frames][-1]
    np.testing.assert_allclose(last.centroids_px[:, 0], CameraModel().rest_x_px + 12.7 * d[-1], atol=0.05)


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
def test_fast_pacing_keeps_only_the_newest_frame(tmp_path: Path, sources: list[FrameSource]) -> None:
    path = tmp_path / "v.avi"
    write_video(path, "FFV1", n=20)
    src = OpenCVSource(str(path), pacing="fast")
    sources.append(src)
    src.open()
    wait_until(lambda: src.info().ended, 20, "the end of the file")
    f = src.read(0.0)
    assert f is not None and f.seq == 19  # the newest; the others were replaced before anyone read them
    info = src.info()
    assert info.frames == 20 and info.dropped == 19
    assert src.read(0.0) is None


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
def test_realtime_stamps_are_spaced_by_the_frame_period(tmp_path: Path, sources: list[FrameSource]) -> None:
    """A file replayed like the camera: frames are released no sooner than their time in the file (50 fps)."""
    path = tmp_path / "v.avi"
    write_video(path, "FFV1", n=10, fps=50.0)
    src = OpenCVSource(str(path), pacing="realtime")
    sources.append(src)
    src.open()
    frames = read_all(src)
    stamps = [f.stamp_ns for f in frames]
    assert frames[-1].seq == 9
    assert stamps[-1] - stamps[0] >= (frames[-1].seq - frames[0].seq) / 50.0 * 1e9 * 0.95


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
def test_close_stops_a_capture_thread_waiting_for_its_consumer(tmp_path: Path) -> None:
    path = tmp_path / "v.avi"
    write_video(path, "FFV1", n=10)
    src = OpenCVSource(str(path), pacing="every")
    src.open()
    wait_until(lambda: src.info().frames >= 1, 20, "the first frame")
    thread = src._thread
    src.close()
    assert thread is not None and not thread.is_alive()
    src.close()  # idempotent


@pytest.mark.system  # a capture thread paced on the wall clock, as a camera is: waits in wall time
def test_absent_camera_is_retried_not_fatal() -> None:
    """A camera that is not there (unplugged) is not an error at open: the source keeps retrying, says why,
    and closes promptly."""
    src = OpenCVSource("/dev/video-palpa-test-absent", reconnect_s=(0.05, 0.1))
    try:
        src.open()
        info = src.info()
        assert info.kind == "device" and not info.connected and "could not open" in info.last_error
        assert src.read(0.05) is None
    finally:
        thread = src._thread
        src.close()
    assert thread is not None and not thread.is_alive()  # close() ended the retrying thread (it joins it)


def test_errors_name_the_source(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="does not exist"):
        OpenCVSource(str(tmp_path / "missing.avi"))
    with pytest.raises(CameraError, match="no file matches"):
        OpenCVSource(str(tmp_path / "img_%05d.png"))
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"not a video at all")
    src = OpenCVSource(str(junk))
    with pytest.raises(CameraError, match="cannot open file"):
        src.open()
    src.close()
    with pytest.raises(ValueError, match="pacing"):
        OpenCVSource(str(junk), pacing="slow")  # type: ignore[arg-type]


def test_parse_device() -> None:
    assert parse_device(0) == (0, "device")
    assert parse_device("2") == (2, "device")
    assert parse_device("/dev/video3") == ("/dev/video3", "device")


def test_sim_source_newest_frame_on_its_clock() -> None:
    clock = MockClock()
    rendered: list[int] = []

    def render(stamp_ns: int) -> np.ndarray:
        rendered.append(stamp_ns)
        return np.zeros((4, 6, 3), np.uint8)

    src = SimSource(render, 10.0, clock.now_ns)
    assert src.read() is None  # not opened
    src.open()
    t0 = clock.now_ns()
    f = src.read()
    assert f is not None and f.seq == 0 and f.stamp_ns == t0
    assert src.read() is None  # the next frame is not due yet
    clock.advance(0.35)  # frames 1, 2, 3 are due; only the newest is rendered
    f = src.read()
    assert f is not None and f.seq == 3 and f.stamp_ns == t0 + 300_000_000
    assert rendered == [t0, t0 + 300_000_000]
    info = src.info()
    assert info.frames == 4 and info.dropped == 2 and (info.width, info.height) == (6, 4)
    src.close()
    assert src.read() is None


def test_sim_source_renders_only_as_far_as_its_world_is_known() -> None:
    clock = MockClock()
    known: list[int | None] = [None]
    rendered: list[int] = []

    def render(stamp_ns: int) -> np.ndarray:
        rendered.append(stamp_ns)
        return np.zeros((4, 6, 3), np.uint8)

    src = SimSource(render, 10.0, clock.now_ns, known_until=lambda: known[0], lead_ns=50_000_000,
                    max_wait_ns=1_000_000_000)
    src.open()
    t0 = clock.now_ns()
    f = src.read()  # nothing known yet: the frame is due now and rendered (the probe off the sample)
    assert f is not None and f.stamp_ns == t0
    known[0] = t0 + 120_000_000
    clock.advance(0.45)  # frames 1-4 due, the world known to 0.12 s: only frame 1 (0.1 <= 0.12 + 0.05) is
    f = src.read()
    assert f is not None and f.seq == 1 and f.stamp_ns == t0 + 100_000_000
    assert src.read() is None  # frame 2 waits for the world, it is not rendered stale nor dropped
    known[0] = t0 + 450_000_000
    f = src.read()
    assert f is not None and f.seq == 4 and src.info().dropped == 2  # then the newest, as ever
    clock.advance(1.2)  # the world stalls more than max_wait behind: frames stream on at now
    f = src.read()
    assert f is not None and f.stamp_ns == t0 + 1_600_000_000
    assert rendered == [t0, t0 + 100_000_000, t0 + 400_000_000, t0 + 1_600_000_000]


def test_sim_camera_shows_a_press_whose_poses_came_late_not_the_arm_where_it_was(spring_phantom: object) -> None:
    clock = MockClock()
    cam = SimCameraSource(spring_phantom, clock.now_ns, pixel_noise_px=0.0, errors=None)  # type: ignore[arg-type]
    cam.open()
    cam.set_pose(clock.now_ns(), 20.0, 20.0, 40.0)  # above the 30 mm high sample
    assert cam.read() is not None and cam.truth is not None and not cam.truth.contact.any()
    t0 = clock.now_ns()
    t_press = t0 + 300_000_000
    clock.advance(0.6)  # the arm pressed 5 mm in at 0.3 s, but the camera's node was starved: no pose heard yet
    early = cam.read()  # the frames up to 50 ms past the last pose may show it (the arm was still above then) ...
    assert early is not None and early.stamp_ns <= t0 + 50_000_000 and not cam.truth.contact.any()
    assert cam.read() is None  # ... a frame at 0.6 s would show the arm above where it pressed: it waits
    for t in range(t_press, clock.now_ns() + 1, 100_000_000):  # the late poses come in, at the robot's rate
        cam.set_pose(t, 20.0, 20.0, 25.0)
    f = cam.read()
    assert f is not None and 0 <= clock.now_ns() - f.stamp_ns < 34_000_000 and cam.truth is not None  # the newest
    assert cam.truth.contact.any() and cam.truth.advance_mm > 4.0


@pytest.fixture
def spring_phantom() -> object:
    return load_phantom("phantoms/springs_037.yaml")


def test_sim_camera_renders_the_forward_model(spring_phantom: object) -> None:
    clock = MockClock()
    # the ideal probe on rods, frictionless: the world's series springs must agree with eq. 5's forward model
    cam = SimCameraSource(spring_phantom, clock.now_ns, tilt_deg=10.0, pixel_noise_px=0.0,  # type: ignore[arg-type]
                          errors=None)
    cam.open()
    f = cam.read()
    assert f is not None and cam.truth is not None
    assert not cam.truth.contact.any() and math.isinf(cam.truth.advance_mm)  # no pose yet: off the sample
    clock.advance(0.1)
    cam.set_pose(clock.now_ns(), 20.0, 20.0, 30.0 - 5.0)  # 5 mm into the 30 mm high sample at the centre
    f = cam.read()
    assert f is not None
    truth = cam.truth
    assert truth is not None and truth.k_t_n_per_mm == 0.37
    gap = [x * 0.0 + y * math.tan(math.radians(10.0)) for x, y in zip(PAPER_GEOMETRY.x_mm, PAPER_GEOMETRY.y_mm,
                                                                      strict=True)]
    assert truth.advance_mm == pytest.approx(5.0 - min(gap))
    expected = forward(PAPER_GEOMETRY, 0.37, truth.advance_mm, 0.0, math.radians(10.0)).dx_mm
    np.testing.assert_allclose(truth.displacement_mm, expected)
    tracker = Tracker(calibration=None, config=TrackerConfig(zero_frames=1))
    tracker.process(Renderer(cam.camera, np.random.default_rng(0)).render(np.zeros(4)))
    r = tracker.process(f.image)
    np.testing.assert_allclose(r.centroids_px, truth.centres_px, atol=0.1)  # one noisy frame (RMS ~0.025 px)
    np.testing.assert_allclose(truth.centres_px[:, 0], np.asarray(cam.camera.rest_x_px) + 12.7 * expected)


def test_sim_camera_noise_defaults_to_the_phantom_and_occlusion(spring_phantom: object) -> None:
    clock = MockClock()
    cam = SimCameraSource(spring_phantom, clock.now_ns)  # type: ignore[arg-type]
    assert cam.camera.jitter_px == 0.3  # the phantom file's noise.pixel default
    cam.open()
    cam.occluded = np.array([False, False, False, True])
    f = cam.read()
    assert f is not None
    r = Tracker().process(f.image)
    assert r.valid.tolist() == [True, True, True, False]
    with pytest.raises(ValueError, match="pan and tilt"):
        SimCameraSource(spring_phantom, clock.now_ns, tilt_deg=90.0)  # type: ignore[arg-type]
