"""Crash safety: a file left by a recorder that never closed it (truncated anywhere, or SIGKILLed for real) is
rebuilt by ``bag recover`` into a valid, indexed MCAP holding everything but at most the last second."""

from __future__ import annotations

import shutil
import signal
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader

from messages import Text
from palpa.net.address import BusAddress
from palpa.node.node import Node
from palpa.record.format import MD_DROPS, MD_NODES, MD_RECORDING, MD_RECOVERY, BagError
from palpa.record.info import bag_info
from palpa.record.reader import iter_file
from palpa.record.recorder import Recorder
from palpa.record.recover import recover
from palpa.record.testing import check_official
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from palpa.testing import NodeHarness
from tests.procs import ProcessGroup, palpa_cmd, wait_until


def _unfinished_recording(tmp_path: Path) -> tuple[Path, list[int]]:
    """A recorder that flushed three times and then 'died' (the file is copied before it is closed)."""
    out = tmp_path / "live.mcap"
    h = NodeHarness(Recorder, {"output": str(out)})
    h.publish(HEARTBEAT_TOPIC, Heartbeat(node="talker", pid=7, host="rig", publishes={"chatter": "Text"},
                                         subscribes={}, counters={}, sent={}, uptime_s=1.0))
    flushed: list[int] = []
    seq = 0
    for _ in range(3):
        for _ in range(25):
            seq += 1
            h.publish("chatter", Text(text=f"m{seq}"))
        h.advance(0.5)
        flushed.append(seq)
    for _ in range(10):  # still in the open chunk when the process dies
        seq += 1
        h.publish("chatter", Text(text=f"m{seq}"))
    crashed = tmp_path / "crashed.mcap"
    shutil.copyfile(out, crashed)
    h.close()
    return crashed, flushed


def test_an_unfinished_file_is_readable_by_the_official_readers_up_to_its_last_flush(tmp_path: Path) -> None:
    crashed, flushed = _unfinished_recording(tmp_path)
    with open(crashed, "rb") as fh:
        texts = [m.data for _, ch, m in make_reader(fh).iter_messages() if ch.topic == "chatter"]
    with open(crashed, "rb") as fh:
        streamed = [r for r in StreamReader(fh).records if isinstance(r, McapMessage)]
    assert len(texts) == flushed[-1] and len([m for m in streamed if m.data in texts]) == flushed[-1]


def test_recover_rebuilds_an_unfinished_file(tmp_path: Path) -> None:
    crashed, flushed = _unfinished_recording(tmp_path)
    # palpa's reader reads it too (up to the last flush), and bag info says it was not finalized
    assert [m.seq for m in iter_file(crashed)] == list(range(1, flushed[-1] + 1))
    assert not bag_info([crashed])["files"][0]["finalized"]
    report = recover(crashed)
    assert report.output == tmp_path / "crashed.recovered.mcap" and not report.finalized
    view = check_official(report.output)
    seqs = [m.seq for m in iter_file(report.output) if m.topic == "chatter"]
    assert seqs == list(range(1, flushed[-1] + 1))  # every flushed chunk; the open one died with the process
    assert view.metadata[MD_RECOVERY]["source_finalized"] == "false"
    assert MD_RECORDING in view.metadata and "talker" in view.metadata[MD_NODES]
    assert view.metadata[MD_DROPS]["chatter"].startswith("{")
    info = bag_info([report.output])
    assert info["files"][0]["finalized"] and info["topics"]["chatter"]["messages"] == flushed[-1]


@pytest.mark.parametrize("cut", [1, 9, 100, 1000, 1500, 2500])
def test_recover_any_truncation(tmp_path: Path, cut: int) -> None:
    """Cut the file anywhere (mid-record, mid-chunk): recovery keeps whole chunks and never fails."""
    crashed, flushed = _unfinished_recording(tmp_path)
    data = crashed.read_bytes()
    if cut >= len(data):
        pytest.skip("file shorter than the cut")
    crashed.write_bytes(data[: len(data) - cut])
    report = recover(crashed, tmp_path / "out.mcap")
    check_official(report.output)
    kept = [m.seq for m in iter_file(report.output) if m.topic == "chatter"]
    assert kept == list(range(1, len(kept) + 1))  # a prefix, in order, nothing invented
    assert len(kept) in (0, *flushed)


def test_recover_refuses_to_overwrite_its_source(tmp_path: Path) -> None:
    crashed, _ = _unfinished_recording(tmp_path)
    with pytest.raises(BagError, match="must differ"):
        recover(crashed, crashed)
    not_mcap = tmp_path / "n.mcap"
    not_mcap.write_bytes(b"definitely not")
    with pytest.raises(BagError, match="not an MCAP file"):
        recover(not_mcap, tmp_path / "n2.mcap")
    assert not (tmp_path / "n2.mcap").exists()


@pytest.mark.system
def test_kill_9_then_recover(ipc_bus: BusAddress, procs: ProcessGroup, env_for, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A real recorder process SIGKILLed mid-run loses at most its last second; recover makes the file whole."""
    out = tmp_path / "killed.mcap"
    env = env_for(ipc_bus)
    rec = procs.start(palpa_cmd("record", "-o", str(out), "chatter"), env=env)
    watch = Node(name="watch", bus=ipc_bus, heartbeat_s=0)
    try:
        beats = watch.subscribe(HEARTBEAT_TOPIC, Heartbeat)
        wait_until(lambda: (hb := beats.next(0.1)) is not None and hb.node == "recorder", 15, "recorder heartbeat")
        talker = procs.start(palpa_cmd("run", "nodes.demo:Talker", "-p", "rate_hz=500"), env=env)

        def recorded() -> int:
            hb = beats.next(0.2)
            c = hb.counters.get("chatter") if hb is not None and hb.node == "recorder" else None
            return c.received if c is not None else 0

        wait_until(lambda: recorded() >= 1000, 20, "the recorder to take 1000 messages")
        rec.signal(signal.SIGKILL)
        killed_ns = time.time_ns()
        assert rec.wait(5) == -signal.SIGKILL
        talker.stop()
    finally:
        watch.close(0)
    assert not bag_info([out])["files"][0]["finalized"]  # no summary: not a finished file
    # yet the official readers read it as it is, up to its last complete chunk (a footer without a summary)
    with open(out, "rb") as fh:
        official = [m.sequence for _, ch, m in make_reader(fh).iter_messages() if ch.topic == "chatter"]
    with open(out, "rb") as fh:
        streamed = sum(1 for r in StreamReader(fh).records if isinstance(r, McapMessage))
    assert len(official) >= 500 and streamed >= len(official)
    report = recover(out)
    view = check_official(report.output)
    msgs = [m for m in iter_file(report.output) if m.topic == "chatter"]
    assert len(msgs) >= 500
    seqs = [m.seq for m in msgs]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # contiguous: nothing lost before the crash
    lost_s = (killed_ns - msgs[-1].log_time) / 1e9
    assert lost_s < 1.0, f"the recovered file ends {lost_s:.2f} s before the kill"
    assert view.metadata[MD_RECOVERY]["source_finalized"] == "false"
