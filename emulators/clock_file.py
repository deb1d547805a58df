"""An emulator on somebody else's clock: co-simulation between a real-time device emulator and a graph whose
clock may fall behind the wall clock (a loaded PC, a process stopped in a debugger, a simulated clock).

The graph's side writes its clock's time into a small shared file (:class:`ClockWriter`); the emulator reads it
(:class:`ClockReader`) and never lets the device's simulated motion run more than a *lead* past it. So when the
graph's process stalls, the emulated device stalls with it after at most the lead, instead of moving on under a
controller that cannot react, as the real device would (the stall is the PC's, which the real rig must not have; a
test that wants to see what a stall does runs the emulator on the wall clock, its default).

The lead lets the motion run on between the writer's updates (one per pass of its loop) instead of stopping at
each. Only the motion should hold: a client blocked in a call that waits for the device (ur_rtde's path upload
waits for the controller to run the new script) would wait forever on a device whose logic held too, since nobody
advances the clock meanwhile (emulators.ur.server.UrEmulator).

The file holds the time in ns (int64, little-endian) and its bitwise complement, so that a reader that meets a
half-written value sees the two disagree and reads again. A file of zeros (nothing written yet) is no clock: the
emulator runs on the wall clock until the first time arrives, and again once the writer releases it.
"""

from __future__ import annotations

import mmap
import os
import struct
from pathlib import Path

__all__ = ["ClockReader", "ClockWriter"]

_FORMAT = "<qq"
_SIZE = struct.calcsize(_FORMAT)


class ClockWriter:
    """Publishes a clock's time (ns, any epoch, never decreasing) to the emulators that follow ``path``."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        with open(self.path, "wb") as f:
            f.write(bytes(_SIZE))
        self._file = open(self.path, "r+b")  # noqa: SIM115 - kept open for the mmap's life, closed by close()
        self._map = mmap.mmap(self._file.fileno(), _SIZE)
        self._last = 0

    def write(self, now_ns: int) -> None:
        """Publish ``now_ns``; a time earlier than the last one published is refused (a clock does not go back)."""
        if now_ns <= 0 or now_ns < self._last:
            raise ValueError(f"ClockWriter: times must be positive and never decrease: {now_ns} after {self._last}")
        self._last = now_ns
        struct.pack_into(_FORMAT, self._map, 0, now_ns, ~now_ns)

    def release(self) -> None:
        """Let the followers run on the wall clock again (a file of zeros), e.g. before closing a client whose
        teardown waits for the device while nobody advances this clock any more."""
        struct.pack_into(_FORMAT, self._map, 0, 0, 0)
        self._last = 0

    def close(self) -> None:
        """Release the followers and close the file (the file stays: a follower may still map it)."""
        self.release()
        self._map.close()
        self._file.close()


class ClockReader:
    """Reads the time a :class:`ClockWriter` publishes at ``path`` (which must exist: the writer creates it)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        with open(self.path, "rb") as f:
            if len(f.read(_SIZE)) != _SIZE:
                raise ValueError(f"{self.path}: not a clock file ({_SIZE} bytes expected); start its writer first")
            self._map = mmap.mmap(f.fileno(), _SIZE, access=mmap.ACCESS_READ)

    def read(self) -> int | None:
        """The last time written (ns), or None while nothing has been written."""
        for _ in range(100):
            now, check = struct.unpack_from(_FORMAT, self._map, 0)
            if now == 0 and check == 0:
                return None
            if check == ~now:
                return int(now)
        raise RuntimeError(f"{self.path}: the clock never read consistently in 100 tries: is it a clock file?")

    def close(self) -> None:
        self._map.close()
