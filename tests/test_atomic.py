"""palpa.atomic, the one write-then-rename: the output is whole or not there, and no temporary is left."""

from __future__ import annotations

from pathlib import Path

import pytest

from palpa.atomic import write_beside, written_beside


@pytest.mark.parametrize("per_writer", [False, True])
def test_a_failed_write_leaves_the_old_output_and_nothing_beside_it(tmp_path: Path, per_writer: bool) -> None:
    out = tmp_path / "out.json"
    write_beside(out, "old\n", per_writer=per_writer)
    with pytest.raises(RuntimeError), written_beside(out, per_writer=per_writer) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"] and out.read_text() == "old\n"
    write_beside(out, b"new\n", per_writer=per_writer)
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"] and out.read_bytes() == b"new\n"


def test_a_stale_partial_is_removed_first_and_a_writers_own_is_hidden(tmp_path: Path) -> None:
    out = tmp_path / "map.npz"
    (tmp_path / "map.npz.partial").write_text("from a killed run")
    with written_beside(out) as tmp:
        assert not tmp.exists()
        tmp.write_text("x")
    with written_beside(out, per_writer=True) as tmp:
        assert tmp.name.startswith(".map.npz.") and tmp.name.endswith(".partial")
        tmp.symlink_to("elsewhere")  # any kind of output: runs/latest is a symlink
    assert out.is_symlink() and [p.name for p in tmp_path.iterdir()] == ["map.npz"]
