"""The launcher's progress view: which payloads count as progress, and what is printed."""

from __future__ import annotations

import io

import msgspec

from palpa.launch.progress import ProgressView, progress_fields


def pack(obj: object) -> bytes:
    return msgspec.msgpack.encode(obj)


def test_progress_fields_take_what_they_understand() -> None:
    got = progress_fields(pack({"progress": 0.5, "state": "scanning", "line": 3, "lines": 10, "eta_s": 12.5,
                                "message": "row 3", "other": [1]}))
    assert got == {"progress": 0.5, "state": "scanning", "line": 3, "lines": 10, "eta_s": 12.5, "message": "row 3"}
    assert progress_fields(pack({"progress": 1.7})) == {"progress": 1.0}  # clamped to 0..1
    assert progress_fields(pack({"progress": 0.2, "line": "three", "state": 4})) == {"progress": 0.2}
    for bad in (pack({"state": "idle"}), pack({"progress": "half"}), pack({"progress": True}), pack([0.5]),
                pack({"progress": float("nan")}), b"\xc1"):
        assert progress_fields(bad) is None


def test_plain_view_prints_on_change_of_5_percent_or_state() -> None:
    out = io.StringIO()
    view = ProgressView("robot/scan_status", out, terminal=False)
    for i in range(101):
        view.update({"progress": i / 100, "state": "scanning" if i < 60 else "returning", "line": i, "lines": 100})
    view.print("[x] WARNING something")
    view.close()
    lines = out.getvalue().splitlines()
    assert lines[0] == "progress   0% scanning  line 0/100"
    assert "progress  60% returning  line 60/100" in lines
    assert "progress 100% returning  line 100/100" in lines
    assert lines[-1] == "[x] WARNING something"
    assert len(lines) == 22  # one line per 5 % (the state change falls on 60 %), plus the warning


def test_terminal_view_draws_a_bar_and_prints_above_it() -> None:
    out = io.StringIO()
    view = ProgressView("robot/scan_status", out, terminal=True)
    view.update({"progress": 0.25, "state": "scanning", "eta_s": 75})
    view.print("[node] ERROR boom [not markup]")
    view.close()
    text = out.getvalue()
    assert "[node] ERROR boom [not markup]" in text
    assert "scanning" in text and "25%" in text and "eta 1:15" in text
