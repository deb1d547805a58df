"""What docs/wire.md promises a client in another language, checked in process: every header integer a uint64 on
the wire (service requests and replies included) while any width is accepted; a heartbeat's schema (its ``sent``
counts itself, ``leaving`` as a node closes, tools drop a leaving node); refusals in plain text; the exact paths
and addresses the page gives; ``palpa service list`` saying where the parameter services are."""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import msgspec
import pytest

import palpa
from messages import Text
from palpa.cli import service as service_cli
from palpa.cli import topic as topic_cli
from palpa.current import launches_dir
from palpa.net.address import default_address, private_dir
from palpa.net.latch import LatchCache
from palpa.net.wire import WIRE_VERSION, Header, HeaderTemplate, decode_header, encode_header
from palpa.runtime_msgs import HEARTBEAT_TOPIC, Heartbeat
from palpa.testing import GraphHarness, MemoryBus
from tests.test_service import Adder, Caller

REPO = Path(__file__).resolve().parent.parent
_INT_KEYS = (b"\xa3seq", b"\xa5stamp", b"\xa3inc", b"\xa2at")


def int_widths(header: bytes) -> dict[str, int]:
    """Header key -> the msgpack type byte of its value, for the integer keys present."""
    found = {}
    for key in _INT_KEYS:
        i = header.find(key)
        if i >= 0:
            found[key[1:].decode()] = header[i + len(key)]
    return found


class Recording(MemoryBus):
    """A memory bus that keeps every envelope's frames as sent."""

    def __init__(self) -> None:
        super().__init__()
        self.frames: list[list[bytes]] = []

    def _route(self, frames: list[bytes], latched: bool) -> None:
        self.frames.append(list(frames))
        super()._route(frames, latched)

    def on(self, topic: str) -> list[list[bytes]]:
        return [f for f in self.frames if f[0] == topic.encode()]


def test_every_header_integer_is_a_uint64_however_small() -> None:
    small = Header(type="Text", seq=1, stamp=2, node="n", latched=True, inc=3, at=4)
    assert int_widths(encode_header(small)) == {"seq": 0xCF, "stamp": 0xCF, "inc": 0xCF, "at": 0xCF}
    assert decode_header(encode_header(small)) == small
    assert int_widths(HeaderTemplate("Text", "n", True, 3, instant=True).pack(1, 2, 4)) == \
        {"seq": 0xCF, "stamp": 0xCF, "inc": 0xCF, "at": 0xCF}
    with pytest.raises(ValueError, match="seq -1 or stamp 0 is not a uint64"):
        encode_header(Header(type="Text", seq=-1, stamp=0, node="n"))


def test_a_header_of_any_integer_width_is_still_accepted() -> None:
    """Wire version 1 peers (and hand-written clients) send the smallest width; receivers take any."""
    plain = msgpack.packb({"type": "Text", "seq": 1, "stamp": 2, "node": "old", "inc": 7})
    assert int_widths(plain)["seq"] == 0x01  # a positive fixint
    assert decode_header(plain) == Header(type="Text", seq=1, stamp=2, node="old", inc=7)


def test_service_requests_and_replies_carry_their_seq_as_uint64() -> None:
    """The gap a JavaScript client hit: a reply's small seq decoded as a number, its own as a BigInt."""
    bus = Recording()
    with GraphHarness([(Adder, None), (Caller, None)], bus=bus) as g:
        g.advance(0.25)
        caller = g.nodes[1]
        assert isinstance(caller, Caller) and caller.results == [1.0, 2.0]
    requests, replies = bus.on("math/add/request"), [f for f in bus.frames if b"/reply/" in f[0]]
    assert len(requests) == 2 and len(replies) == 2
    for frames in requests + replies:
        assert int_widths(frames[1])["seq"] == 0xCF, frames[1]
    assert [msgpack.unpackb(f[1])["seq"] for f in requests] == [1, 2]  # one count per (client id, service)
    assert [msgpack.unpackb(f[1])["seq"] for f in replies] == [1, 2]   # each reply: its request's seq


class Quiet(palpa.Node):
    def setup(self) -> None:
        self.out = self.publisher("chatter", Text)


def heartbeats(bus: Recording) -> list[tuple[dict[str, Any], Heartbeat]]:
    return [(msgpack.unpackb(f[1]), msgspec.msgpack.decode(f[2], type=Heartbeat)) for f in bus.on(HEARTBEAT_TOPIC)]


def test_a_heartbeat_counts_itself_says_its_wire_version_and_leaving_as_the_node_closes() -> None:
    bus = Recording()
    g = GraphHarness(bus=bus)
    node = g.add(Quiet, heartbeat_s=1.0)
    node.out.publish(Text(text="one"))
    node._heartbeat()
    node._heartbeat()
    g.close()
    beats = heartbeats(bus)
    assert len(beats) >= 3  # (one more when the first was due as the node set up)
    assert [h["seq"] for h, _ in beats] == [hb.sent[HEARTBEAT_TOPIC] for _, hb in beats] == \
        list(range(1, len(beats) + 1))
    assert [hb.state for _, hb in beats] == ["running"] * (len(beats) - 1) + ["leaving"]
    assert beats[-1][1].sent["chatter"] == 1 and all(hb.wire == WIRE_VERSION == 2 for _, hb in beats)


def test_a_node_without_heartbeats_sends_no_leaving_one() -> None:
    bus = Recording()
    with GraphHarness(bus=bus) as g:
        g.add(Quiet)  # heartbeat_s=0: a tool's node, never listed
    assert bus.on(HEARTBEAT_TOPIC) == []


def _beat(node: str, state: str = "running", services: dict[str, str] | None = None) -> Heartbeat:
    return Heartbeat(node=node, pid=1, host="h", publishes={}, subscribes={}, counters={}, sent={}, uptime_s=1.0,
                     state=state, services=services or {})


class _Beats:
    """What a tool's heartbeat subscription hands out, in order (collect_heartbeats' input)."""

    def __init__(self, beats: list[Heartbeat]) -> None:
        self._beats = iter(beats)

    def next(self, timeout: float) -> Heartbeat | None:
        return next(self._beats, None)


class _ToolNode:
    def __init__(self, beats: list[Heartbeat]) -> None:
        self._beats = beats

    def subscribe(self, topic: str, cls: type[Heartbeat]) -> _Beats:
        return _Beats(self._beats)

    def __enter__(self) -> _ToolNode:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def test_tools_drop_a_node_whose_latest_heartbeat_says_leaving() -> None:
    beats = [_beat("a"), _beat("b"), _beat("b", "leaving"), _beat("c", "leaving"), _beat("c")]
    got = topic_cli.collect_heartbeats(_ToolNode(beats), 0.05)  # type: ignore[arg-type]
    assert sorted(got) == ["a", "c"]  # c came back: its latest heartbeat is a running one


@pytest.fixture
def graph_beats(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Heartbeat]]:
    beats: list[Heartbeat] = []
    monkeypatch.setattr(service_cli, "tool_node", lambda args, name: _ToolNode(beats))
    yield beats


def test_service_list_says_the_parameter_services_are_hidden_and_how_to_show_them(
        graph_beats: list[Heartbeat], capsys: pytest.CaptureFixture[str]) -> None:
    params = {"_palpa/param/talker/get": "ParamGet -> ParamValues", "_palpa/param/talker/set": "ParamSet -> ParamValues"}
    graph_beats.append(_beat("talker", services=params))
    args = argparse.Namespace(wait=0.05, all=False)
    assert service_cli.run_list(args) == 0
    out = capsys.readouterr().out
    assert "no services but 2 parameter services" in out and "palpa service list --all" in out
    assert service_cli.run_list(argparse.Namespace(wait=0.05, all=True)) == 0
    listed = capsys.readouterr().out
    assert "_palpa/param/talker/get  [ParamGet -> ParamValues]  server: talker" in listed
    assert "not shown" not in listed and "parameter services" not in listed
    graph_beats.append(_beat("adder", services={"math/add": "AddRequest -> AddReply", **params}))
    assert service_cli.run_list(args) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "math/add  [AddRequest -> AddReply]  server: adder"
    assert "and 4 parameter services" in out
    graph_beats.clear()
    assert service_cli.run_list(args) == 1
    assert "no services" in capsys.readouterr().err


def test_a_refusal_reason_is_plain_text() -> None:
    header = encode_header(Header(type="Text", seq=1, stamp=1, node="js"))
    why = LatchCache(frozenset()).check(b"js/notlatched", [header, msgpack.packb({"text": "x"})])
    assert why == "topic 'js/notlatched' is not latched (header without latched: true, not in bus.latched)"


def test_the_paths_and_addresses_wire_md_gives_are_the_real_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PALPA_CURRENT", raising=False)
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    uid = os.getuid()
    assert launches_dir() == Path(f"/tmp/palpa-{uid}/launches") == private_dir() / "launches"
    assert default_address() == f"ipc:///tmp/palpa-{uid}/bus"
    doc = (REPO / "docs" / "wire.md").read_text()
    assert "`/tmp/palpa-<uid>/launches`" in doc and "`ipc:///tmp/palpa-<uid>/bus`" in doc
    assert "`$XDG_RUNTIME_DIR/palpa/launches`" in doc and "`ipc://$XDG_RUNTIME_DIR/palpa/bus`" in doc
    assert "palpa-<uid>.current" not in doc and "}.current" not in doc and "palpa/current" not in doc
    # the Python example at the end of the page reads the same folder
    assert 'or f"/tmp/palpa-{os.getuid()}/launches"' in doc


def test_the_python_example_of_wire_md_writes_a_version_2_header() -> None:
    doc = (REPO / "docs" / "wire.md").read_text()
    code = doc.split("```python", 1)[1].split("```", 1)[0]
    helper = code[code.index("def header"):code.index("\nctx =")]
    scope: dict[str, Any] = {"msgpack": msgpack, "time": __import__("time")}
    exec(helper, scope)  # the page's own helper, as a reader would paste it
    frame = scope["header"]("Text", 1, "my_client")
    assert int_widths(frame) == {"seq": 0xCF, "stamp": 0xCF}
    assert decode_header(frame).seq == 1 and decode_header(frame).node == "my_client"
