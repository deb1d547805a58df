"""Algorithm 1 tracker (models/tracker.py) on rendered frames with known sphere positions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.camera_render import CameraModel, Renderer, true_centroids_px
from models.kalman import steady_state_gain
from models.tracker import (
    Calibration,
    Tracker,
    TrackerConfig,
    TrackResult,
    annotate,
    default_regions,
)

QUIET = CameraModel(jitter_px=0.0)  # image noise, blur and drift, but no centroid jitter


def run(tracker: Tracker, renderer: Renderer, displacements: np.ndarray, occluded: np.ndarray | None = None
        ) -> tuple[list[TrackResult], np.ndarray]:
    results: list[TrackResult] = []
    drawn = []
    for i, d in enumerate(displacements):
        frame = renderer.render(d, i / 30, None if occluded is None else occluded[i])
        drawn.append(renderer.last_centres_px.copy())
        results.append(tracker.process(frame))
    return results, np.asarray(drawn)


def test_raw_centroids_match_drawn_spheres_with_default_noise() -> None:
    """Default renderer (0.3 px jitter, 2 DN noise, blur, drift): raw centroids vs the spheres as drawn."""
    rng = np.random.default_rng(11)
    d = np.cumsum(rng.uniform(0.0, 0.04, (300, 4)), axis=0)  # slow random compression, up to ~6 mm
    res, drawn = run(Tracker(), Renderer(CameraModel(), rng), d)
    raw = np.asarray([r.centroids_px for r in res])
    assert all(r.valid.all() for r in res)
    rms = np.sqrt(np.mean((raw - drawn) ** 2, axis=(0, 1)))
    assert (rms < 0.05).all(), rms


def test_filtered_centroid_error_within_0_2_px_rms() -> None:
    """The 0.3 px centroid noise after the Kalman filter, against the true (nominal) positions, still markers."""
    rng = np.random.default_rng(12)
    m = CameraModel()
    d = np.tile([1.0, 2.0, 3.0, 4.0], (400, 1))
    res, _ = run(Tracker(), Renderer(m, rng), d)
    filt = np.asarray([r.filtered_x_px for r in res])[50:]
    truth = true_centroids_px(m, d[0])[:, 0]
    rms = float(np.sqrt(np.mean((filt - truth) ** 2)))
    k = steady_state_gain()
    assert rms < 0.2
    assert rms == pytest.approx(0.3 * math.sqrt(k / (2 - k)), rel=0.35)  # what the filter should achieve


def test_mask_moments_also_accurate() -> None:
    rng = np.random.default_rng(13)
    res, drawn = run(Tracker(TrackerConfig(centroid="mask")), Renderer(QUIET, rng), rng.uniform(0, 8, (60, 4)))
    raw = np.asarray([r.centroids_px for r in res])
    assert float(np.sqrt(np.mean((raw - drawn) ** 2))) < 0.1


def test_first_frame_zero_reference_and_mm_mapping() -> None:
    """zero_frames=1 is the paper's I_0: the first frame's raw centroids are the rest positions."""
    rng = np.random.default_rng(14)
    renderer = Renderer(QUIET, rng)
    tracker = Tracker(TrackerConfig(zero_frames=1))
    first = tracker.process(renderer.render(np.zeros(4)))
    assert first.zeroed and tracker.calibration is not None
    np.testing.assert_allclose(tracker.calibration.rest_x_px, first.centroids_px[:, 0])
    np.testing.assert_allclose(first.displacement_mm, 0.0, atol=1e-12)
    d = np.array([0.5, 1.0, 2.0, 7.5])
    for i in range(80):
        r = tracker.process(renderer.render(d, i / 30))
    np.testing.assert_allclose(r.displacement_mm, d, atol=0.004)  # 0.05 px


def test_zero_reference_waits_for_frames_with_every_marker() -> None:
    rng = np.random.default_rng(15)
    renderer = Renderer(CameraModel(), rng)
    tracker = Tracker(TrackerConfig(zero_frames=10))
    hidden = np.array([False, False, True, False])
    for _ in range(12):  # a marker is missing: nothing is averaged
        r = tracker.process(renderer.render(np.zeros(4), occluded=hidden))
        assert not r.zeroed and np.isnan(r.displacement_mm).all()
    assert tracker.zero_progress == 0
    for i in range(10):
        r = tracker.process(renderer.render(np.zeros(4)))
        assert r.zeroed == (i == 9)
    assert tracker.calibration is not None
    # the average of 10 noisy frames: much closer to the truth than one 0.3 px sample typically is
    np.testing.assert_allclose(tracker.calibration.rest_x_px, CameraModel().rest_x_px, atol=0.35)


def test_stored_calibration_and_reversed_direction() -> None:
    m = CameraModel(direction=-1.0, rest_x_px=(140.0, 300.0, 460.0, 620.0), jitter_px=0.0)
    cal = Calibration(m.rest_x_px, m.px_per_mm, -1.0)
    tracker = Tracker(calibration=cal)
    renderer = Renderer(m, np.random.default_rng(16))
    d = np.array([1.0, 4.0, 9.0, 0.2])
    r = tracker.process(renderer.render(d))
    assert r.zeroed
    np.testing.assert_allclose(r.displacement_mm, d, atol=0.01)
    assert Calibration.from_dict(cal.to_dict()) == cal


def test_lost_marker_predicts_only_then_recovers() -> None:
    rng = np.random.default_rng(17)
    renderer = Renderer(CameraModel(), rng)
    tracker = Tracker()
    d = np.full(4, 2.0)
    for i in range(40):
        tracker.process(renderer.render(d, i / 30))
    before = tracker.kalman.x.copy()
    p_before = tracker.kalman.p.copy()
    hidden = np.array([False, True, False, False])
    for i in range(5):
        r = tracker.process(renderer.render(d, 0.0, occluded=hidden))
        assert r.valid.tolist() == [True, False, True, True]
        assert np.isnan(r.centroids_px[1]).all() and r.m00[1] == 0.0
        assert r.filtered_x_px[1] == before[1]  # predict-only: held
        assert math.isfinite(r.displacement_mm[1])
        assert tracker.kalman.p[1] == pytest.approx(p_before[1] + 0.09 * (i + 1))
        assert tracker.windows[1] == (tracker.regions or ())[1]  # searched in its whole region
    r = tracker.process(renderer.render(d))
    assert r.valid.all() and abs(r.filtered_x_px[1] - before[1]) < 1.0


def test_marker_found_far_away_after_a_loss_restarts_its_filter() -> None:
    renderer = Renderer(QUIET, np.random.default_rng(18))
    tracker = Tracker()
    for _ in range(35):
        tracker.process(renderer.render(np.zeros(4)))
    hidden = np.array([True, False, False, False])
    tracker.process(renderer.render(np.zeros(4), occluded=hidden))
    d = np.array([5.0, 0.0, 0.0, 0.0])  # moved 63.5 px while unseen
    r = tracker.process(renderer.render(d))
    assert r.valid[0]
    assert r.displacement_mm[0] == pytest.approx(5.0, abs=0.02)  # no slow Kalman crawl towards it


def test_windows_follow_a_moving_marker() -> None:
    """A ramp of 0.8 px/frame: the window re-centres on the filtered x each frame; no whole-region searches."""
    renderer = Renderer(CameraModel(), np.random.default_rng(19))
    tracker = Tracker()
    n = 150
    d = np.zeros((n, 4))
    d[:, 2] = np.linspace(0.0, 9.0, n)
    res, drawn = run(tracker, renderer, d)
    assert all(r.valid.all() for r in res)
    regions = tracker.regions
    assert regions is not None
    box = tracker.windows[2]
    assert box != regions[2] and box[2] - box[0] == 2 * 24 + 1  # a window, not the strip
    assert box[0] < drawn[-1, 2, 0] < box[2]
    raw = np.asarray([r.centroids_px for r in res])
    assert np.abs(raw[:, 2, 0] - drawn[:, 2, 0]).max() < 0.15  # the window never clipped the sphere
    lag = drawn[-1, 2, 0] - res[-1].filtered_x_px[2]
    v = 9.0 * 12.7 / (n - 1)
    k = steady_state_gain()
    assert lag == pytest.approx(v * (1 - k) / k, abs=1.5)  # the random-walk filter's ramp lag


def test_sudden_jump_beyond_the_window_is_found_in_the_region() -> None:
    renderer = Renderer(QUIET, np.random.default_rng(20))
    tracker = Tracker()
    for _ in range(35):
        tracker.process(renderer.render(np.zeros(4)))
    r = tracker.process(renderer.render(np.array([0.0, 4.0, 0.0, 0.0])))  # +51 px in one frame
    assert r.valid.all()
    assert r.centroids_px[1, 0] == pytest.approx(CameraModel().rest_x_px[1] + 4.0 * 12.7, abs=0.1)


def test_hsv_range_is_configurable() -> None:
    red = CameraModel(sphere_bgr=(30.0, 40.0, 200.0), jitter_px=0.0)  # OpenCV hue ~2
    frame = Renderer(red, np.random.default_rng(21)).render(np.zeros(4))
    assert not Tracker().process(frame).valid.any()  # green range: nothing
    r = Tracker(TrackerConfig(hsv_lower=(0, 100, 50), hsv_upper=(10, 255, 255))).process(frame)
    assert r.valid.all()
    np.testing.assert_allclose(r.centroids_px, true_centroids_px(red, np.zeros(4)), atol=0.1)


def test_custom_regions_and_annotation() -> None:
    m = CameraModel(jitter_px=0.0)
    regions = tuple((max(0, int(x) - 16), int(y) - 30, min(640, int(x) + 150), int(y) + 30)
                    for x, y in zip(m.rest_x_px, m.y_px, strict=True))
    tracker = Tracker(TrackerConfig(regions=regions))
    frame = Renderer(m, np.random.default_rng(22)).render(np.zeros(4))
    r = tracker.process(frame)
    assert r.valid.all()
    out = annotate(frame, r, tracker.windows)
    assert out.shape == frame.shape and not np.array_equal(out, frame)


def test_default_regions_are_vertical_strips() -> None:
    assert default_regions(640, 480) == ((0, 0, 160, 480), (160, 0, 320, 480), (320, 0, 480, 480), (480, 0, 640, 480))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"hsv_lower": (180, 0, 0)}, "hsv_lower"),
    ({"hsv_lower": (90, 0, 0), "hsv_upper": (80, 255, 255)}, "exceeds"),
    ({"regions": ((10, 0, 5, 10),)}, "regions"),
    ({"zero_frames": 0}, "zero_frames"),
    ({"window_half_px": (1, 10)}, "window_half_px"),
    ({"centroid": "median"}, "centroid"),
])
def test_bad_configs_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        TrackerConfig(**kwargs)  # type: ignore[arg-type]


def test_frame_errors_say_what_is_wrong() -> None:
    tracker = Tracker(TrackerConfig(regions=((0, 0, 700, 480),) * 4))
    with pytest.raises(ValueError, match="beyond the 640x480 frame"):
        tracker.process(np.zeros((480, 640, 3), np.uint8))
    tracker = Tracker()
    with pytest.raises(ValueError, match="BGR uint8"):
        tracker.process(np.zeros((480, 640), np.uint8))
    tracker.process(np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(ValueError, match="differs from the first frame"):
        tracker.process(np.zeros((240, 320, 3), np.uint8))
