"""Device clock -> host clock for a sensor that stamps its own samples (the fibre DAQ's 32-bit µs counter).

The host only sees when a line arrived (sampling instant + a variable, positive transport delay); the
estimator below recovers the sampling instant on the host clock from many such pairs.
"""

from __future__ import annotations

from collections import deque


class ClockOffsetEstimator:
    """Maps device time to host time: ``host ≈ device + offset(device)``.

    Minimum-latency filter with drift: every ``block_s`` of device time keeps the sample
    with the smallest ``host - device`` (the one that crossed the wire fastest); a line is
    fitted through those block minima over the last ``window_s``, after discarding minima
    that sit well above the fit (a block in which the host was busy). Before three blocks
    exist the plain minimum is used. Drift is clamped to ``max_drift_ppm``.
    """

    def __init__(self, window_s: float = 10.0, block_s: float = 0.25, max_drift_ppm: float = 20000.0) -> None:
        if not 0 < block_s < window_s:
            raise ValueError(f"need 0 < block_s < window_s, got block_s={block_s}, window_s={window_s}")
        self._window_ns = int(window_s * 1e9)
        self._block_ns = int(block_s * 1e9)
        self._max_drift = max_drift_ppm * 1e-6
        self.reset()

    def reset(self) -> None:
        """Forget everything (after a reconnect or a device reboot)."""
        self._blocks: deque[tuple[int, int]] = deque()  # (device_ns, min host-device)
        self._cur: tuple[int, int, int] | None = None  # (block index, device_ns, min d)
        self._fit: tuple[int, float, float] | None = None  # (t_ref, offset at t_ref, slope)

    def update(self, device_ns: int, host_ns: int) -> None:
        """Add one (device stamp, host receive stamp) pair, both in ns."""
        d = host_ns - device_ns
        idx = device_ns // self._block_ns
        if self._cur is None or idx != self._cur[0]:
            if self._cur is not None:
                self._blocks.append((self._cur[1], self._cur[2]))
                while self._blocks and device_ns - self._blocks[0][0] > self._window_ns:
                    self._blocks.popleft()
                self._refit()
            self._cur = (idx, device_ns, d)
        elif d < self._cur[2]:
            self._cur = (idx, device_ns, d)

    def _refit(self) -> None:
        pts = list(self._blocks)
        if len(pts) < 3:
            self._fit = None
            return
        for _ in range(2):
            t_ref = pts[-1][0]
            n = len(pts)
            mx = sum(t - t_ref for t, _ in pts) / n
            my = sum(d for _, d in pts) / n
            sxx = sum((t - t_ref - mx) ** 2 for t, _ in pts)
            slope = sum((t - t_ref - mx) * (d - my) for t, d in pts) / sxx if sxx > 0 else 0.0
            slope = max(-self._max_drift, min(self._max_drift, slope))
            a = my - slope * mx
            resid = [d - (a + slope * (t - t_ref)) for t, d in pts]
            mad = sorted(abs(r) for r in resid)[n // 2]
            keep = [p for p, r in zip(pts, resid, strict=True) if r <= 3.0 * mad + 20_000]
            if len(keep) == n or len(keep) < 3:
                break
            pts = keep
        self._fit = (t_ref, a, slope)

    @property
    def ready(self) -> bool:
        """True once at least one sample was seen."""
        return self._cur is not None

    @property
    def drift_ppm(self) -> float:
        """Estimated device clock rate error (ppm; positive: device clock slow)."""
        return 0.0 if self._fit is None else self._fit[2] * 1e6

    def offset_ns(self, device_ns: int | None = None) -> int | None:
        """Offset (host - device, ns) at ``device_ns`` (default: the latest sample)."""
        if self._cur is None:
            return None
        if device_ns is None:
            device_ns = self._cur[1]
        if self._fit is None:
            return min([self._cur[2], *(d for _, d in self._blocks)])
        t_ref, a, slope = self._fit
        return round(a + slope * (device_ns - t_ref))

    def to_host_ns(self, device_ns: int) -> int | None:
        """Device stamp (ns) expressed on the host clock, or None before the first sample."""
        off = self.offset_ns(device_ns)
        return None if off is None else device_ns + off
