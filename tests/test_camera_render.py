"""The probe-camera renderer (models/camera_render.py): geometry, sub-pixel accuracy, noise, drift, occlusion."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from models.camera_render import CameraModel, Renderer, marker_x_px, render, true_centroids_px

CLEAN = CameraModel(jitter_px=0.0, noise_dn=0.0, drift_amplitude=0.0)


def weighted_centroid(frame: np.ndarray, cx: float, cy: float, bg: float, half: int = 20) -> tuple[float, float]:
    """Background-subtracted green-channel centroid in a box around (cx, cy): an independent reference measure."""
    x0, y0 = int(cx) - half, int(cy) - half
    g = frame[y0:y0 + 2 * half + 1, x0:x0 + 2 * half + 1, 1].astype(np.float64) - bg
    g[g < 0] = 0
    ys, xs = np.mgrid[y0:y0 + g.shape[0], x0:x0 + g.shape[1]]
    return float((g * xs).sum() / g.sum()), float((g * ys).sum() / g.sum())


def test_default_frame_geometry_and_colours() -> None:
    m = CameraModel()
    frame = Renderer(m, np.random.default_rng(0)).render(np.zeros(4))
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    for x, y in zip(m.rest_x_px, m.y_px, strict=True):
        b, g, r = frame[int(y), int(x)].tolist()
        assert g > 150 and b < 80 and r < 90  # green sphere centre
    assert abs(float(frame[20:60, 300:340].mean()) - np.mean(m.background_bgr)) < 1.5  # background elsewhere


def test_scale_and_direction() -> None:
    m = CameraModel(px_per_mm=10.0, direction=-1.0, rest_x_px=(100.0, 250.0, 400.0, 550.0))
    np.testing.assert_allclose(marker_x_px(m, [0.0, 1.0, 2.5, -1.0]), [100.0, 240.0, 375.0, 560.0])
    xy = true_centroids_px(m, np.zeros(4))
    np.testing.assert_allclose(xy[:, 1], m.y_px)


def test_full_stroke_stays_inside_each_strip() -> None:
    """Defaults: 0..10 mm of indenter travel keeps sphere j (radius + blur) inside the j-th 160 px strip."""
    m = CameraModel()
    for d in (0.0, 10.0):
        x = marker_x_px(m, np.full(4, d))
        reach = m.sphere_radius_px + 3 * m.blur_sigma_px
        for j in range(4):
            assert 160 * j <= x[j] - reach and x[j] + reach < 160 * (j + 1)


def test_subpixel_positions_are_unbiased() -> None:
    """Anti-aliased spheres at random sub-pixel positions: an intensity centroid lands within 0.03 px."""
    rng = np.random.default_rng(1)
    r = Renderer(CLEAN, rng)
    errors = []
    for _ in range(40):
        d = rng.uniform(0.0, 10.0, 4)
        frame = r.render(d)
        for (x, y) in true_centroids_px(CLEAN, d):
            mx, my = weighted_centroid(frame, x, y, CLEAN.background_bgr[1])
            errors.append((mx - x, my - y))
    err = np.abs(np.asarray(errors))
    assert err.max() < 0.03, err.max(axis=0)


def test_patch_blur_equals_whole_frame_blur() -> None:
    """Blurring each sphere's patch (the fast path) gives the same image as blurring the whole frame."""
    sharp = CameraModel(jitter_px=0.0, noise_dn=0.0, drift_amplitude=0.0, blur_sigma_px=0.0)
    blurred = CameraModel(jitter_px=0.0, noise_dn=0.0, drift_amplitude=0.0, blur_sigma_px=1.5)
    d = np.array([0.3, 2.71, 5.5, 9.9])
    ours = Renderer(blurred, np.random.default_rng(0)).render(d).astype(np.float64)
    ref = cv2.GaussianBlur(Renderer(sharp, np.random.default_rng(0)).render(d).astype(np.float64), (0, 0), 1.5)
    assert np.abs(ours - ref).max() <= 1.0 + 1e-9  # two roundings to whole DN at most


def test_jitter_is_the_centroid_noise_and_reproducible() -> None:
    m = CameraModel(noise_dn=0.0)  # default jitter: 0.3 px, the paper-level raw centroid noise
    a, b = Renderer(m, np.random.default_rng(5)), Renderer(m, np.random.default_rng(5))
    offsets = []
    for i in range(200):
        fa, fb = a.render(np.zeros(4), i / 30), b.render(np.zeros(4), i / 30)
        np.testing.assert_array_equal(fa, fb)
        offsets.append(a.last_centres_px - true_centroids_px(m, np.zeros(4)))
    sd = np.asarray(offsets).reshape(-1, 2).std(axis=0)
    np.testing.assert_allclose(sd, 0.3, rtol=0.1)


def test_sensor_noise_level() -> None:
    m = CameraModel(noise_dn=3.0, drift_amplitude=0.0)
    r = Renderer(m, np.random.default_rng(2))
    patches = np.asarray([r.render(np.zeros(4))[0:100, 250:330].astype(np.float64) for _ in range(5)])
    sd = float(np.std(patches - np.asarray(m.background_bgr)))  # per channel, about its own background level
    assert sd == pytest.approx(math.sqrt(9 + 1 / 12), rel=0.05)  # integer noise: + the rounding variance
    assert not np.array_equal(patches[0], patches[1])  # a different noise window each frame


def test_lighting_drift_scales_the_image() -> None:
    m = CameraModel(noise_dn=0.0, jitter_px=0.0, drift_amplitude=0.1, drift_period_s=4.0)
    r = Renderer(m, np.random.default_rng(0))
    low, mid, high = (float(r.render(np.zeros(4), t).mean()) for t in (3.0, 0.0, 1.0))
    assert m.gain(1.0) == pytest.approx(1.1) and m.gain(3.0) == pytest.approx(0.9)
    assert high / mid == pytest.approx(1.1, rel=0.02) and low / mid == pytest.approx(0.9, rel=0.02)


def test_occluded_marker_is_not_drawn() -> None:
    r = Renderer(CLEAN, np.random.default_rng(0))
    frame = r.render(np.zeros(4), occluded=np.array([False, True, False, False]))
    x, y = int(CLEAN.rest_x_px[1]), int(CLEAN.y_px[1])
    patch = frame[y - 15:y + 16, x - 15:x + 16]
    assert (patch == np.asarray(CLEAN.background_bgr, dtype=np.uint8)).all()  # flat background
    assert frame[int(CLEAN.y_px[0]), int(CLEAN.rest_x_px[0]), 1] > 150


def test_sphere_partly_outside_the_image_is_clipped() -> None:
    m = CameraModel(rest_x_px=(-5.0, 200.0, 400.0, 636.0), jitter_px=0.0)
    frame = Renderer(m, np.random.default_rng(0)).render(np.zeros(4))
    assert frame[int(m.y_px[0]), 0, 1] > 150 and frame[int(m.y_px[3]), 639, 1] > 150


def test_one_shot_render_matches_the_stream_renderer_image_model() -> None:
    frame = render(CLEAN, np.full(4, 3.0), np.random.default_rng(0))
    ref = Renderer(CLEAN, np.random.default_rng(0)).render(np.full(4, 3.0))
    np.testing.assert_array_equal(frame, ref)  # without noise or jitter both are deterministic


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"rest_x_px": (1.0, 2.0)}, "y_px: expected 2 values"),
    ({"direction": 0.5}, "direction"),
    ({"px_per_mm": 0.0}, "px_per_mm"),
    ({"sphere_bgr": (0.0, 300.0, 0.0)}, "sphere_bgr"),
    ({"noise_dn": -1.0}, "noise_dn"),
    ({"width": 8}, "width and height"),
])
def test_bad_models_are_refused(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CameraModel(**kwargs)  # type: ignore[arg-type]


def test_wrong_displacement_shape_is_a_caller_error() -> None:
    r = Renderer(CameraModel(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="displacements_mm"):
        r.render(np.zeros(3))
    with pytest.raises(ValueError, match="occluded"):
        r.render(np.zeros(4), occluded=[True])
