"""What native code (a C++ robot library) writes straight to file descriptor 2, caught so that a failure it
explains ends as one line (the driver's error, holding that text) instead of a stray line before it."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator

__all__ = ["native_stderr"]


@contextlib.contextmanager
def native_stderr() -> Iterator[list[str]]:
    """Catch file descriptor 2 meanwhile; the yielded list holds the text once the block is over (one string,
    whitespace collapsed). Without an exception the text is written on to the real stderr (nothing lost).

    Meant for calls that hold the GIL while they block (ur_rtde's connect): no Python thread writes meanwhile."""
    said: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    failed = False
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield said
        except BaseException:
            failed = True
            raise
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            raw = tmp.read()
            said.append(" ".join(raw.decode(errors="replace").split()))
            if raw and not failed:
                os.write(2, raw)
