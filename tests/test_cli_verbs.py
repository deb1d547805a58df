"""The ROS 2 verbs a user reaches for (issue 42) on a live bus: ``node info``, ``topic info|type|bw``, ``service
type``, ``param describe``, ``param list`` over every node, and ``topic hz`` naming its time base and counting gaps
from sequence numbers."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import msgspec
import pytest

import palpa
from messages import Text, Trigger, TriggerResult
from palpa.cli.main import main
from palpa.cli.topic import bw_line, hz_line, time_base
from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.net.wire import Header, TopicStats
from tests.procs import short_ipc_base

pytestmark = pytest.mark.system


class Gadget(palpa.Node):
    """Publishes Text on chatter every tick, serves gadget/reset, and has documented parameters."""

    class Params(palpa.Params):
        rate_hz: palpa.Positive = 50.0
        """How often chatter is sent."""
        label: str = "g"

    params: Params

    def setup(self) -> None:
        self.pub = self.publisher("chatter", Text, direct=False)
        self.service("gadget/reset", Trigger, TriggerResult, lambda req: TriggerResult(success=True, message=""))
        self.timer(1.0 / self.params.rate_hz, lambda: self.pub.publish(Text(text=self.params.label * 10)))


@contextmanager
def running(make: Callable[[], palpa.Node]) -> Iterator[palpa.Node]:
    stop, ready = threading.Event(), threading.Event()
    made: list[palpa.Node] = []

    def body() -> None:
        with make() as node:
            made.append(node)
            ready.set()
            while not stop.is_set():
                node.spin_once(0.02)

    t = threading.Thread(target=body, daemon=True)
    t.start()
    assert ready.wait(10)
    try:
        yield made[0]
    finally:
        stop.set()
        t.join(10)


@pytest.fixture
def graph() -> Iterator[str]:
    with Bus(BusAddress.parse(f"ipc://{short_ipc_base()}")) as b:
        assert b.address is not None
        address = b.address
        with running(lambda: Gadget(name="gadget", bus=address, heartbeat_s=0.2)), \
                running(lambda: palpa.Node(name="listener", bus=address, heartbeat_s=0.2)) as listener:
            listener.subscribe("chatter", Text, lambda m: None)
            yield str(address)


def test_node_topic_and_service_verbs(graph: str, capsys: pytest.CaptureFixture[str]) -> None:
    bus = ["--bus", graph, "--wait", "1.0"]
    assert main(["node", "info", "gadget", *bus]) == 0
    out = capsys.readouterr().out
    assert "Publishers:\n    chatter: Text  (sent " in out and "Service Servers:\n    gadget/reset: Trigger" in out
    assert "_palpa/" not in out
    assert main(["node", "info", "gadgte", *bus]) == 1
    assert "no node 'gadgte' heard (did you mean 'gadget'?)" in capsys.readouterr().err
    assert main(["topic", "info", "chatter", *bus]) == 0
    assert capsys.readouterr().out.splitlines() == ["Type: Text", "Publisher count: 1", "Subscription count: 1"]
    assert main(["topic", "info", "chatter", "-v", *bus]) == 0
    verbose = capsys.readouterr().out
    assert "  publisher  gadget  pid" in verbose and "  subscriber listener  pid" in verbose
    assert main(["topic", "type", "/chatter", *bus]) == 0
    assert capsys.readouterr().out.strip() == "Text"
    assert main(["topic", "type", "chater", *bus]) == 1
    assert "(did you mean 'chatter'?)" in capsys.readouterr().err
    assert main(["service", "type", "gadget/reset", "--bus", graph]) == 0
    assert capsys.readouterr().out.strip() == "Trigger -> TriggerResult"
    assert main(["topic", "bw", "chatter", "--duration", "1.5", "--bus", graph]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    size = len(msgspec.msgpack.encode(Text(text="g" * 10, stamp_ns=1)))
    assert "/s from " in last and f"min {size} B  max {size} B" in last and "(wall time)" in last


def test_graph_of_the_running_graph_from_heartbeats(graph: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "live.svg"
    assert main(["graph", "--bus", graph, "--wait", "1.0", "-o", str(out)]) == 0
    assert "2 nodes, 1 topics (0 direct), 1 services" in capsys.readouterr().out
    svg = out.read_text()
    assert "gadget" in svg and "listener" in svg and "chatter" in svg and "[Text]" in svg and "gadget/reset" in svg
    assert main(["graph", "--bus", f"ipc://{short_ipc_base()}", "--wait", "0.3", "-o", str(tmp_path / "x.png")]) == 1
    assert "no node heartbeats heard" in capsys.readouterr().err


def test_param_describe_and_list_over_every_node(graph: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["param", "describe", "gadget", "rate_hz", "--bus", graph]) == 0
    out = capsys.readouterr().out
    assert "type:        float" in out and "default:     50.0" in out
    assert "description: > 0; How often chatter is sent." in out
    assert main(["param", "describe", "gadget", "rate", "--bus", graph]) == 1
    assert "no parameter 'rate' (did you mean 'rate_hz'?)" in capsys.readouterr().err
    assert main(["param", "list", "--bus", graph, "--wait", "1.0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "gadget:" in lines and "listener:" in lines
    assert lines[lines.index("gadget:") + 1].startswith("  rate_hz: float = 50.0")


def test_hz_names_its_time_base_and_counts_gaps_by_sequence_number(graph: str,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    address = BusAddress.parse(graph)
    with running(lambda: palpa.Node(name="sim", bus=address, heartbeat_s=0)) as sim:
        done = threading.Event()

        def send() -> None:  # a sim-clock publisher's envelopes (they carry 'at'); 3 and 4 never sent
            for i, seq in enumerate([1, 2, 5, 6, 7, 8] * 1):
                stamp = 1_000_000_000 + i * 10_000_000
                sim.publish_raw("simtopic", Header(type="Text", seq=seq, stamp=stamp, node="sim", at=stamp),
                                msgspec.msgpack.encode(Text(text="x", stamp_ns=stamp)))
            done.set()

        timer = threading.Timer(1.0, send)
        timer.start()
        assert main(["topic", "hz", "simtopic", "--duration", "2.5", "--bus", graph]) == 0
        timer.join()
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert done.is_set() and "rate 100.00 Hz (simulated time)" in last and "gaps 2" in last and "received 6" in last
    assert main(["topic", "hz", "chatter", "--duration", "1.5", "--bus", graph]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "(wall time)" in last and "gaps 0 (by sequence number)" in last


def test_the_lines_without_a_bus() -> None:
    assert time_base({"simulated": 3, "wall": 0}) == "simulated time"
    assert time_base({"simulated": 0, "wall": 3}) == "wall time"
    assert time_base({"simulated": 1, "wall": 1}).startswith("mixed")
    stats = TopicStats(received=3, gaps=1, restarts=1)
    assert hz_line([0, 100_000_000, 200_000_000], stats, "wall time").startswith("rate 10.00 Hz (wall time)")
    assert "gaps 1  restarts 1" in hz_line([0, 1], stats)
    assert bw_line([(0, 100), (1_000_000_000, 300)]).startswith("300 B/s from 2 messages")
    assert "min 100 B  max 300 B" in bw_line([(0, 100), (1_000_000_000, 300)])
