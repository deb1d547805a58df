"""A launch file's ``record`` section: the recorder starts first and is heard before any node starts, and stops
last, so the recording holds every message of the run."""

from __future__ import annotations

import importlib.util
import re
import textwrap
from pathlib import Path

import pytest

from tests.procs import ProcessGroup, palpa_cmd

REPO = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.skipif(importlib.util.find_spec("palpa.record.recorder") is None,
                                reason="palpa.record.recorder (the recorder node) is not available")


def test_recorder_starts_first_and_stops_last(procs: ProcessGroup, tmp_path: Path) -> None:
    from palpa.record.reader import iter_bag

    file = tmp_path / "rec.yaml"
    file.write_text(textwrap.dedent("""
        record: {topics: ["chatter.*"]}
        nodes:
          - {name: listener, node: nodes.demo:Listener}
          - {name: talker, node: nodes.demo:Talker, params: {rate_hz: 50.0, count: 40}, required: true}
    """))
    run_dir = tmp_path / "run"
    proc = procs.start(palpa_cmd("launch", str(file), "--run-dir", str(run_dir)), cwd=str(REPO))
    assert proc.wait(60) == 0, proc.output()
    log = (run_dir / "launch.log").read_text()
    order = [m.group(1) for m in re.finditer(
        r"INFO (started recorder|recorder ready|started listener|started talker|listener stopped on SIGINT|"
        r"recorder stopped on SIGINT)", log)]
    assert order == ["started recorder", "recorder ready", "started listener", "started talker",
                     "listener stopped on SIGINT", "recorder stopped on SIGINT"], log
    messages = list(iter_bag([run_dir / "recording.mcap"]))
    chatter = [m.seq for m in messages if m.topic == "chatter"]
    # A publisher's very first messages can be dropped by ZeroMQ while its connection to the proxy is being set
    # up (before any subscriber is known to it): no subscriber can get those. The recorder must have everything
    # from the first message any other node heard up to the last one sent.
    heard = [int(n) for n in re.findall(r"heard 'hello (\d+)'", (run_dir / "listener.log").read_text())]
    assert heard, (run_dir / "listener.log").read_text()
    assert chatter and chatter[0] <= heard[0], (chatter, heard)
    assert chatter == list(range(chatter[0], 41)), f"recorded chatter seqs {chatter}"
    assert {m.topic for m in messages} <= {"chatter", "chatter_len", "_palpa/log"}  # the recorder keeps logs
    assert "chatter_len" in {m.topic for m in messages}
