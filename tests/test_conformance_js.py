"""The wire format as a foreign client meets it: conformance/js/client.mjs, a Node.js client written from docs/wire.md
alone (zeromq.js + @msgpack/msgpack, installed by ``make conformance-js``), does its five jobs on a live
launch/talker_listener.yaml: subscribe, publish, latch, parameters, heartbeat. The graph's own heartbeats and
``palpa node list`` check what it claims."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from palpa.cli.main import main
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from tests.launching import launched, spin_until
from tests.procs import REPO, ProcessGroup

pytestmark = pytest.mark.system

CLIENT = REPO / "conformance" / "js" / "client.mjs"


def _node_or_fail() -> str:
    node = shutil.which("node")
    if node is None:
        pytest.fail("no `node` on PATH: the conformance client needs Node.js >= 18")
    if not (CLIENT.parent / "node_modules" / "zeromq").is_dir():
        pytest.fail("conformance/js has no node_modules: run `make conformance-js` (npm ci, pinned by its lock file)")
    return node


def _lines(output: str) -> dict[str, dict[str, Any]]:
    """The client's JSON lines by job (the first line, the bus it found, as 'bus')."""
    out: dict[str, dict[str, Any]] = {}
    for line in output.splitlines():
        if line.startswith("{"):
            item = json.loads(line)
            out[item.get("job", "bus")] = item
    return out


def test_a_nodejs_client_does_the_five_jobs_on_a_live_graph(procs: ProcessGroup, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    node_exe = _node_or_fail()
    with launched(procs, "launch/talker_listener.yaml", tmp_path / "run") as (launch, node):
        bus = (tmp_path / "run" / "bus.address").read_text().strip()
        beats: dict[str, Heartbeat] = {}
        node.subscribe(HEARTBEAT_TOPIC, Heartbeat, lambda hb: beats.__setitem__(hb.node, hb))
        spin_until(node, lambda: {"talker", "listener"} <= beats.keys(), 30, "the graph's heartbeats", launch)
        # no --bus: the client finds the launch as docs/wire.md says, by its entry among the running launches
        js = procs.start([node_exe, str(CLIENT), "--deadline", "90"], cwd=str(CLIENT.parent))
        try:
            js.wait_for_output('"job":"heartbeat"', 100)
        except AssertionError as exc:
            raise AssertionError(f"{exc}\n--- the launch:\n{launch.output()[-3000:]}") from None
        jobs = _lines(js.output())
        assert jobs["bus"]["found_by"] == f"the launch in {(tmp_path / 'run').resolve()}", jobs["bus"]
        for job in ("subscribe", "publish", "latch", "params"):
            assert jobs[job]["ok"], js.output()
        assert jobs["heartbeat"]["failed_jobs"] == 0
        assert jobs["publish"]["listener_after_bad"]["decode_errors"] == 1
        assert jobs["latch"]["refusal"].startswith("topic 'js/notlatched' is not latched")
        assert jobs["params"]["rate_hz_before"] == 10 and jobs["params"]["rate_hz_after"] == 20

        # what the graph itself counted: the listener took the client's messages without a gap and one bad one;
        # the talker's parameter services saw the client's requests numbered per service, without gaps
        def requests() -> dict[str, tuple[int, int]]:
            return {t: (c.received, c.gaps) for t, c in beats["talker"].counters.items()
                    if t.startswith("_palpa/param/talker/")}

        spin_until(node, lambda: "js_node" in beats and beats["listener"].counters["chatter"].decode_errors == 1
                   and all(received == 2 for received, _ in requests().values()), 10,
                   "heartbeats of the listener and the talker counting the client's messages", launch)
        chatter = beats["listener"].counters["chatter"]
        assert (chatter.gaps, chatter.decode_errors, chatter.duplicates, chatter.restarts) == (0, 1, 0, 0)
        assert requests() == {"_palpa/param/talker/get/request": (2, 0), "_palpa/param/talker/set/request": (2, 0)}
        mine = beats["js_node"]
        assert mine.wire == 2 and mine.state == "running" and mine.publishes["chatter"] == "Text"
        assert mine.sent["chatter"] == 21  # 20 good and the bad one: seq counts per (node, topic)

        capsys.readouterr()
        assert main(["node", "list", "--bus", bus]) == 0
        listed = capsys.readouterr().out
        assert any(line.startswith("js_node  pid ") for line in listed.splitlines()), listed
        # a foreign node need not serve parameters: palpa param says there is no server
        assert main(["param", "list", "js_node", "--bus", bus, "--timeout", "0.5"]) == 1
        assert "_palpa/param/js_node/get': no server announced it" in capsys.readouterr().err

        assert js.stop(10) == 0  # SIGINT: its last heartbeat says leaving, and tools drop it
        spin_until(node, lambda: beats["js_node"].state == "leaving", 10, "js_node's leaving heartbeat", launch)
        assert main(["node", "list", "--bus", bus]) == 0
        assert "js_node" not in capsys.readouterr().out


def test_the_client_refuses_a_bad_command_line() -> None:
    node_exe = _node_or_fail()
    done = subprocess.run([node_exe, str(CLIENT), "--deadline", "soon"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "--deadline must be a positive number" in done.stderr
    done = subprocess.run([node_exe, str(CLIENT), "--bus", "udp://x"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "expected ipc://PATH, tcp://HOST:PORT" in done.stderr
