"""Tracker benchmark: Algorithm 1 on per-marker windows (models.tracker) vs a naive full-frame pipeline.

Both run single-threaded (``cv2.setNumThreads(1)``) over the same rendered 640x480 frames of a press (the
renderer's default noise: 0.3 px centroid jitter, 2 DN sensor noise, blur, lighting drift):

* ``naive``  -- the baseline of issue 7: ``cvtColor`` BGR->HSV of the whole frame, ``inRange`` of the whole
  frame, then ``moments`` of the mask in each of the four vertical strips (nothing else);
* ``ours``   -- ``Tracker.process``: HSV, inRange and grayscale-weighted moments on a 49x37 window per marker,
  re-centred each frame, plus the Kalman filter, validity and pixel -> mm mapping (more work per marker, less
  image).

Rounds of each alternate, so that load from other processes on this machine hits both alike; the reported
figure of each is the median round. Targets: ours >= 3000 frames/s and >= 2x naive. Prints a table, then one
JSON line.

    .venv/bin/python bench/tracker.py [--frames 300] [--rounds 7] [--seconds 0.4]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.camera_render import CameraModel, Renderer  # noqa: E402  (after the sys.path line)
from models.tracker import Tracker, TrackerConfig, default_regions  # noqa: E402

Image = np.ndarray


def make_frames(n: int, seed: int = 0) -> tuple[list[Image], np.ndarray]:
    """``n`` frames of a press (indenters 0 -> ~8 mm and back) and the drawn centres (n, 4, 2)."""
    model = CameraModel()
    renderer = Renderer(model, np.random.default_rng(seed))
    phase = np.sin(np.linspace(0.0, np.pi, n)) ** 2
    d = phase[:, None] * np.array([8.0, 5.2, 6.4, 7.1])
    frames, centres = [], []
    for i in range(n):
        frames.append(renderer.render(d[i], i / 30.0))
        centres.append(renderer.last_centres_px.copy())
    return frames, np.asarray(centres)


def naive_pipeline(lower: np.ndarray, upper: np.ndarray) -> Callable[[Image], list[float]]:
    """Full-frame HSV + inRange, then moments of the mask per vertical strip; returns the 4 centroid x."""
    strips = default_regions(640, 480)

    def process(frame: Image) -> list[float]:
        mask = cv2.inRange(cv2.cvtColor(frame, cv2.COLOR_BGR2HSV), lower, upper)
        out = []
        for x0, y0, x1, y1 in strips:
            m = cv2.moments(mask[y0:y1, x0:x1], True)
            out.append(x0 + m["m10"] / m["m00"] if m["m00"] > 0 else float("nan"))
        return out

    return process


def time_round(fn: Callable[[Image], object], frames: list[Image], seconds: float) -> float:
    """Frames per second of ``fn`` over ``frames`` (cycled) for about ``seconds`` of wall time."""
    n, i, start = 0, 0, time.perf_counter()
    deadline = start + seconds
    while True:
        for _ in range(50):
            fn(frames[i])
            i = (i + 1) % len(frames)
        n += 50
        now = time.perf_counter()
        if now >= deadline:
            return n / (now - start)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=300, help="distinct rendered frames (cycled)")
    ap.add_argument("--rounds", type=int, default=7, help="alternating timed rounds of each pipeline")
    ap.add_argument("--seconds", type=float, default=0.4, help="wall time per round")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    frames, centres = make_frames(args.frames)
    config = TrackerConfig()
    lower, upper = np.array(config.hsv_lower, np.uint8), np.array(config.hsv_upper, np.uint8)
    naive = naive_pipeline(lower, upper)

    # accuracy check on one pass (the benchmark is meaningless if ours does not track)
    tracker = Tracker(config)
    raw = np.asarray([tracker.process(f).centroids_px for f in frames])
    ours_rms = float(np.sqrt(np.nanmean((raw - centres) ** 2)))
    ours_valid = bool(np.isfinite(raw).all())
    naive_x = np.asarray([naive(f) for f in frames])
    naive_rms = float(np.sqrt(np.nanmean((naive_x - centres[:, :, 0]) ** 2)))

    tracker = Tracker(config)
    tracker.process(frames[0])
    ours_fps, naive_fps = [], []
    for _ in range(args.rounds):
        ours_fps.append(time_round(tracker.process, frames, args.seconds))
        naive_fps.append(time_round(naive, frames, args.seconds))
    ours, base = statistics.median(ours_fps), statistics.median(naive_fps)
    ratio = ours / base
    print(f"tracker benchmark: {len(frames)} rendered 640x480 frames, 1 OpenCV thread, "
          f"{args.rounds} alternating rounds of {args.seconds} s (median)")
    print(f"{'pipeline':<40}{'frames/s':>12}{'us/frame':>12}{'x naive':>10}{'centroid RMS px':>18}")
    print(f"{'naive: full-frame HSV+inRange+moments':<40}{base:>12.0f}{1e6 / base:>12.1f}{1.0:>10.2f}"
          f"{naive_rms:>18.3f}")
    print(f"{'ours: per-marker windows + Kalman':<40}{ours:>12.0f}{1e6 / ours:>12.1f}{ratio:>10.2f}"
          f"{ours_rms:>18.3f}")
    print(f"rounds ours {[round(v) for v in ours_fps]}, naive {[round(v) for v in naive_fps]}")
    print("targets: ours >= 3000 frames/s and >= 2x naive (naive's RMS is whole-pixel mask moments; ours is "
          "grayscale-weighted, vs the drawn centres)")
    met = ours >= 3000 and ratio >= 2.0 and ours_valid
    print(json.dumps({"bench": "tracker", "frames": len(frames), "width": 640, "height": 480, "threads": 1,
                      "ours_fps": round(ours, 1), "naive_fps": round(base, 1), "ratio": round(ratio, 3),
                      "ours_centroid_rms_px": round(ours_rms, 4), "naive_centroid_rms_px": round(naive_rms, 4),
                      "targets_met": met}))
    return 0 if ours_valid else 1


if __name__ == "__main__":
    sys.exit(main())
