"""docs/limits.md states the numbers the code uses: every row naming a constant (`module.NAME`) gives its value."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

DOC = Path(__file__).resolve().parent.parent / "docs" / "limits.md"
ROW = re.compile(r"^\| [^|]+ \| `(palpa(?:\.\w+)+)\.(\w+)` \| ([0-9][0-9.]*)")


def test_every_number_in_docs_limits_is_the_constant_the_code_uses() -> None:
    rows = [m.groups() for line in DOC.read_text().splitlines() if (m := ROW.match(line))]
    assert len(rows) >= 15
    for module, name, written in rows:
        value = getattr(importlib.import_module(module), name)
        number = float(written) if "." in written else int(written)
        assert number == value, f"docs/limits.md says {module}.{name} = {written}; the code has {value}"
