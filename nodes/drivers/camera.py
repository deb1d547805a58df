"""Frame sources for the camera tracker: one small interface, a real OpenCV backend and a clocked sim backend.

:class:`FrameSource` is what the node uses: ``open()``, ``read(timeout_s) -> Frame | None`` (the newest frame not
yet returned; older ones are dropped and counted, as a tracker wants the present, not a backlog), ``close()`` and
``info()``.

:class:`OpenCVSource` wraps ``cv2.VideoCapture``: a camera by index (``0``) or device path (``/dev/video2``), a
video file (``run3.avi``), or an image sequence (``frames/%04d.png``), captured in its own thread. Stamps are
``time.time_ns()`` taken right after ``grab()`` returns (the host wall clock, the bus's time base), before the
frame is decoded. A camera that fails is reopened with back-off; a file ends. Files are paced by ``pacing``:
``realtime`` at the file's frame rate (a replay behaves like the camera; frames the consumer misses are dropped),
``fast`` as fast as they decode (newest-only, so a slow consumer drops frames), ``every`` as fast as the
consumer takes them (no drops: for analysing a recorded experiment frame by frame).

:class:`SimSource` produces frames from a callable ``render(stamp_ns) -> image`` at ``rate_hz`` of a given clock
(the node's clock, so a mock or simulated clock drives it without threads).
"""

from __future__ import annotations

import glob
import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, NamedTuple, Protocol, runtime_checkable

import cv2
import numpy as np
import numpy.typing as npt

from nodes.drivers.host_clock import host_ns

__all__ = ["CameraError", "Frame", "FrameSource", "OpenCVSource", "SimSource", "SourceInfo", "parse_device"]

log = logging.getLogger(__name__)

Image = npt.NDArray[np.uint8]
Pacing = Literal["realtime", "fast", "every"]


class CameraError(Exception):
    """A frame source cannot be opened (the message names the device or file and why)."""


class Frame(NamedTuple):
    """One captured image: host stamp (ns, see the source), capture sequence number (gaps = dropped), BGR uint8."""

    stamp_ns: int
    seq: int
    image: Image


@dataclass(frozen=True)
class SourceInfo:
    """State and counters of a frame source.

    kind: ``device``, ``file``, ``sequence`` or ``sim``; width/height (px) and fps are 0 until known;
    frames: captured; dropped: captured but replaced by a newer frame before being read;
    ended: a file or sequence reached its end (no more frames will come).
    """

    name: str
    kind: str
    connected: bool = False
    width: int = 0
    height: int = 0
    fps: float = 0.0
    frames: int = 0
    dropped: int = 0
    reconnects: int = 0
    ended: bool = False
    last_error: str = ""


@runtime_checkable
class FrameSource(Protocol):
    """What the camera tracker node needs from a camera."""

    def open(self) -> None:
        """Start capturing; raises :class:`CameraError` when the source cannot be used at all."""
        ...

    def read(self, timeout_s: float = 0.0) -> Frame | None:
        """The newest frame not returned before, waiting up to ``timeout_s``; None if there is none."""
        ...

    def close(self) -> None:
        """Stop capturing and release the device (idempotent, bounded in time)."""
        ...

    def info(self) -> SourceInfo:
        """Current state and counters."""
        ...


_PATTERN = re.compile(r"%0?(\d*)d")


def parse_device(device: int | str) -> tuple[int | str, str]:
    """(value for cv2.VideoCapture, kind) for a device index, a device path, a video file or a ``%d`` pattern.

    Raises :class:`CameraError` for a file or sequence that does not exist.
    """
    if isinstance(device, int) or (isinstance(device, str) and device.strip().isdigit()):
        return int(device), "device"
    path = str(device)
    if path.startswith("/dev/"):
        return path, "device"
    if _PATTERN.search(path):
        pattern = _PATTERN.sub(lambda m: "[0-9]" * int(m.group(1)) if m.group(1) else "[0-9]*", glob.escape(path))
        if not glob.glob(pattern):
            raise CameraError(f"image sequence {path!r}: no file matches (looked for {pattern})")
        return path, "sequence"
    if not Path(path).is_file():
        raise CameraError(f"video file {path!r} does not exist")
    return path, "file"


class OpenCVSource:
    """``cv2.VideoCapture`` in a capture thread that keeps only the newest frame (see the module docstring)."""

    def __init__(
        self,
        device: int | str,
        *,
        pacing: Pacing = "realtime",
        api_preference: int = cv2.CAP_ANY,
        reconnect_s: tuple[float, float] = (0.5, 5.0),
        clock: Callable[[], int] = host_ns,
    ) -> None:
        if pacing not in ("realtime", "fast", "every"):
            raise ValueError(f"OpenCVSource: pacing must be realtime, fast or every, got {pacing!r}")
        self._target, kind = parse_device(device)
        self._api = api_preference
        self._pacing = pacing
        self._backoff = reconnect_s
        self._clock = clock
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._cap: cv2.VideoCapture | None = None
        self._latest: Frame | None = None
        self._unread = False
        self._info = SourceInfo(name=str(device), kind=kind)

    # -- FrameSource -----------------------------------------------------------------------------------------
    def open(self) -> None:
        """Open the capture (a file or sequence that cannot be opened raises; a camera is retried)."""
        if self._thread is not None:
            return
        self._stop.clear()
        if not self._try_open() and self._info.kind != "device":
            raise CameraError(f"cannot open {self._info.kind} {self._info.name!r}: {self._info.last_error}")
        if self._cap is None:
            log.warning("camera %s not available yet (%s); retrying", self._info.name, self._info.last_error)
        self._thread = threading.Thread(target=self._run, name=f"camera {self._info.name}", daemon=True)
        self._thread.start()

    def read(self, timeout_s: float = 0.0) -> Frame | None:
        with self._cond:
            if not self._unread and timeout_s > 0:
                self._cond.wait_for(lambda: self._unread or self._info.ended or self._stop.is_set(), timeout_s)
            if not self._unread:
                return None
            self._unread = False
            self._cond.notify_all()  # pacing "every": the capture thread may fetch the next frame
            return self._latest

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("camera %s: capture thread did not stop within %.1f s", self._info.name, timeout_s)
                return  # it still owns the capture; releasing it under a blocked grab() could crash
        self._release()

    def info(self) -> SourceInfo:
        with self._cond:
            return self._info

    # -- capture thread --------------------------------------------------------------------------------------
    def _update(self, **changes: object) -> None:
        with self._cond:
            self._info = replace(self._info, **changes)  # type: ignore[arg-type]
            self._cond.notify_all()

    def _try_open(self) -> bool:
        cap = cv2.VideoCapture(self._target, self._api)
        if not cap.isOpened():
            cap.release()
            self._update(connected=False, last_error="cv2.VideoCapture could not open it")
            return False
        self._cap = cap
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self._update(connected=True, width=int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                     height=int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), fps=fps if fps > 0 else 0.0, last_error="")
        return True

    def _release(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def _run(self) -> None:
        backoff = self._backoff[0]
        seq = 0
        start_mono: float | None = None  # the file's clock starts when its first frame is out, not at open
        while not self._stop.is_set():
            cap = self._cap
            if cap is None:  # a camera that is absent or was lost
                if self._stop.wait(backoff):
                    break
                backoff = min(backoff * 2, self._backoff[1])
                if self._try_open():
                    backoff = self._backoff[0]
                    self._update(reconnects=self._info.reconnects + 1)
                    log.info("camera %s (re)opened", self._info.name)
                continue
            ok = cap.grab()
            stamp = self._clock()
            if start_mono is None:
                start_mono = time.monotonic()
            image = cap.retrieve()[1] if ok else None
            if image is None:
                if self._info.kind != "device":
                    self._update(ended=True, connected=False, last_error="end of file")
                    break
                self._release()
                self._update(connected=False, last_error="camera stopped delivering frames")
                log.warning("camera %s lost; reconnecting", self._info.name)
                continue
            with self._cond:
                dropped = self._info.dropped + (1 if self._unread else 0)
                self._latest = Frame(stamp, seq, np.asarray(image, dtype=np.uint8))
                self._unread = True
                self._info = replace(self._info, frames=self._info.frames + 1, dropped=dropped,
                                     width=image.shape[1], height=image.shape[0])
                self._cond.notify_all()
                if self._pacing == "every" and self._info.kind != "device":
                    self._cond.wait_for(lambda: not self._unread or self._stop.is_set())
            seq += 1
            if self._pacing == "realtime" and self._info.kind != "device" and self._info.fps > 0:
                # Hold each file frame until its time on the file's clock, as the camera would.
                due = (start_mono or time.monotonic()) + seq / self._info.fps
                delay = due - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break


class SimSource:
    """Frames from ``render(stamp_ns) -> image`` at ``rate_hz`` on ``clock`` (ns).

    ``read`` returns the newest frame due by the clock's now (stamped at its due time), rendering only
    that one; frames due earlier and never read are counted as dropped and skipped in ``seq``.
    ``realtime``: ``read(timeout_s)`` may sleep (up to the timeout) until the next frame is due, for use
    with a wall clock; with a mock or simulated clock leave it False.

    ``known_until`` (a simulated world fed from the bus): the latest instant the world is known at (the newest
    robot pose the renderer was given; None: none yet). A frame is rendered only up to ``lead_ns`` past it, so that
    a pose stream arriving late (a starved process on a wall clock) delays the frames instead of showing them the
    arm where it was: a real camera sees the present. When the world is more than ``max_wait_ns`` behind (the pose
    stream stalled), frames stream on at the clock's now, with what the world last knew: a stalled pose stream
    must not look like a dead camera.
    """

    def __init__(self, render: Callable[[int], Image], rate_hz: float, clock: Callable[[], int], *,
                 name: str = "sim", realtime: bool = False, known_until: Callable[[], int | None] | None = None,
                 lead_ns: int = 50_000_000, max_wait_ns: int = 1_000_000_000) -> None:
        if not rate_hz > 0:
            raise ValueError(f"SimSource: rate_hz must be > 0, got {rate_hz}")
        self._render = render
        self._period_ns = round(1e9 / rate_hz)
        self._clock = clock
        self._realtime = realtime
        self._known_until = known_until
        self._lead_ns = lead_ns
        self._max_wait_ns = max_wait_ns
        self._t0: int | None = None
        self._next_seq = 0
        self._info = SourceInfo(name=name, kind="sim", fps=float(rate_hz))

    def open(self) -> None:
        if self._t0 is None:
            self._t0 = self._clock()
        self._info = replace(self._info, connected=True)

    def read(self, timeout_s: float = 0.0) -> Frame | None:
        if self._t0 is None or not self._info.connected:
            return None
        now = self._clock()
        until = self._rendered_until(now)
        due_seq = (until - self._t0) // self._period_ns
        if due_seq < self._next_seq:
            if until < now or not (self._realtime and timeout_s > 0):
                return None
            wait_s = (self._t0 + self._next_seq * self._period_ns - now) / 1e9
            if wait_s > timeout_s:
                return None
            time.sleep(max(0.0, wait_s))
            due_seq = self._next_seq
        stamp = self._t0 + due_seq * self._period_ns
        image = self._render(stamp)
        skipped = int(due_seq - self._next_seq)
        self._info = replace(self._info, frames=self._info.frames + 1 + skipped, dropped=self._info.dropped + skipped,
                             width=image.shape[1], height=image.shape[0])
        self._next_seq = due_seq + 1
        return Frame(stamp, int(due_seq), image)

    def _rendered_until(self, now: int) -> int:
        """The latest frame stamp that may be rendered at ``now`` (class doc: ``known_until``)."""
        known = self._known_until() if self._known_until is not None else None
        if known is None or now - known > self._max_wait_ns:
            return now
        return min(now, known + self._lead_ns)

    def close(self) -> None:
        self._info = replace(self._info, connected=False)

    def info(self) -> SourceInfo:
        return self._info
