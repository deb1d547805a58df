"""The respawn policy of a launched node: a node that failed (exited non-zero) and asks for respawn starts again
after ``respawn_delay``, doubled at each consecutive failure up to a minute, until ``respawn_max_retries`` (< 0: no
limit). A run of at least half a minute counts as stable: the failures before it are forgotten. A node that exited
0 has finished and is never respawned. Split from palpa.launch.supervisor, which carries the decision out."""

from __future__ import annotations

from palpa.launch.nodeproc import NodeProc

__all__ = ["next_respawn"]

_BACKOFF_CAP_S = 60.0
_STABLE_S = 30.0  # a run at least this long resets the respawn backoff


def next_respawn(p: NodeProc, code: int, now: float) -> float | None:
    """How long after ``now`` node ``p``, which exited with ``code``, starts again (counted in ``p.failures``), or
    None when it does not."""
    spec = p.spec
    if now - p.started_at >= _STABLE_S:
        p.failures = 0
    retries = spec.respawn_max_retries
    if spec.respawn and code != 0 and (retries < 0 or p.failures < retries):
        p.failures += 1
        delay: float = min(_BACKOFF_CAP_S, spec.respawn_delay * 2 ** (p.failures - 1))
        return delay
    return None
