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

pytestmark = [pytest.mark.system, pytest.mark.skipif(importlib.util.find_spec("palpa.record.recorder") is None,
                                reason="palpa.record.recorder (the recorder node) is not available")]


def test_recorder_starts_first_and_stops_last(procs: ProcessGroup, tmp_path: Path) -> None:
    from palpa.record.reader import iter_bag

    # The talker talks until the listener (required) has heard 20: the launch then stops the talker, the recorder
    # last. (A talker that stopped by itself after a fixed count raced the listener's start-up: on a loaded machine
    # it had finished before the listener subscribed, and the test had nothing to compare.)
    file = tmp_path / "rec.yaml"
    file.write_text(textwrap.dedent("""
        record: {topics: ["chatter.*"]}
        nodes:
          - {name: listener, node: nodes.demo:Listener, params: {count: 20}, required: true}
          - {name: talker, node: nodes.demo:Talker, params: {rate_hz: 50.0}}
    """))
    run_dir = tmp_path / "run"
    proc = procs.start(palpa_cmd("launch", str(file), "--run-dir", str(run_dir)), cwd=str(REPO))
    assert proc.wait(60) == 0, proc.output()
    log = (run_dir / "launch.log").read_text()
    order = [m.group(1) for m in re.finditer(
        r"INFO (started recorder|recorder ready|started listener|started talker|"
        r"stopping: required node listener ended|talker stopped on SIGINT|recorder stopped on SIGINT)", log)]
    assert order == ["started recorder", "recorder ready", "started listener", "started talker",
                     "stopping: required node listener ended", "talker stopped on SIGINT", "recorder stopped on SIGINT"], log
    messages = list(iter_bag([run_dir / "recording.mcap"]))
    chatter = [m.seq for m in messages if m.topic == "chatter"]
    # A publisher's very first messages can be dropped by ZeroMQ while its connection to the proxy is being set
    # up (before any subscriber is known to it): no subscriber can get those. The recorder must have everything
    # from the first message any other node heard up to the last one the talker sent.
    heard = [int(n) for n in re.findall(r"heard 'hello (\d+)'", (run_dir / "listener.log").read_text())]
    # at least 20: under load the messages queued while the listener started come in one batch, heard to its end
    assert len(heard) >= 20, (run_dir / "listener.log").read_text()
    sent = [int(n) for n in re.findall(r"sent (\d+)", (run_dir / "talker.log").read_text())]
    assert len(sent) == 1 and sent[0] >= heard[-1], (run_dir / "talker.log").read_text()
    assert chatter and chatter[0] <= heard[0], (chatter, heard)
    assert chatter == list(range(chatter[0], sent[0] + 1)), f"recorded chatter seqs {chatter}, sent {sent[0]}"
    assert {m.topic for m in messages} <= {"chatter", "chatter_len", "_palpa/log"}  # the recorder keeps logs
    assert "chatter_len" in {m.topic for m in messages}
