"""Logging what a peer can make happen as often as it likes (a refused handshake, a message over a limit) without
letting it fill the log: every event is counted, and at most one line per kind of event and interval is written.

The first event of a kind is logged at once; later ones within ``interval_s`` are only counted, and the next line
of that kind says how many there were since the previous line. The counts are exact; only lines are saved.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

__all__ = ["LOG_INTERVAL_S", "LogThrottle"]

LOG_INTERVAL_S = 5.0
"""At most one log line per kind of refusal in this many seconds (the rest are counted)."""
_KINDS_MAX = 256


class LogThrottle:
    """At most one line per ``kind`` every ``interval_s`` seconds of ``now`` (a clock in seconds); counts all."""

    def __init__(self, log: logging.Logger, interval_s: float = LOG_INTERVAL_S,
                 now: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._interval = interval_s
        self._now = now
        self._last: dict[str, float] = {}
        self._since: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        """Events per kind, all of them (logged or not)."""
        self.lines = 0
        """Lines written so far."""

    def event(self, kind: str, level: int, msg: str, *args: object) -> bool:
        """Count one event of ``kind``; log ``msg % args`` (with how many went unlogged since the last line) when
        this kind's last line is ``interval_s`` old or there was none. True when a line was written."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        since = self._since.get(kind, 0)
        now = self._now()
        last = self._last.get(kind)
        if last is not None and now - last < self._interval:
            self._since[kind] = since + 1
            return False
        if last is None and len(self._last) >= _KINDS_MAX:  # kinds come from code, not peers; a bound all the same
            self._last.clear()
            self._since.clear()
        self._last[kind] = now
        self._since[kind] = 0
        if since:
            msg += " (and %d more like it in the last %.0f s)"
            args = (*args, since, now - last if last is not None else 0.0)
        self._log.log(level, msg, *args)
        self.lines += 1
        return True
