"""The bus's latch service at its limits over a real ZeroMQ socket (issue 39): deep nesting refused with the cache
thread alive, a full cache that still takes a later client's values, a bounded watcher table. The pure units are in
test_bus_limits.py."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator

import msgpack
import pytest
import zmq

import palpa
from palpa.net.bus import Bus
from palpa.net.latch import MAX_CLIENTS_PER_PEER, MAX_WATCHES
from palpa.net.wire import MAX_NESTING
from tests.procs import bus_spec, replies_until_pong, wait_until
from tests.test_bus_limits import header, nested
from tests.test_service import Adder, AddReply, AddRequest

pytestmark = pytest.mark.system

TEXT = bytes(msgpack.packb({"text": "ok"}))


@pytest.fixture
def ctx() -> Iterator[zmq.Context[zmq.Socket[bytes]]]:
    context: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
    yield context
    context.destroy(0)


def dealer(ctx: zmq.Context[zmq.Socket[bytes]], bus: Bus) -> zmq.Socket[bytes]:
    assert bus.address is not None
    sock = ctx.socket(zmq.DEALER)
    sock.linger = 0
    sock.connect(bus.address.latch)
    return sock


def test_deep_nesting_is_refused_and_the_cache_thread_survives(ctx: zmq.Context[zmq.Socket[bytes]]) -> None:
    with Bus(bus_spec("ipc"), latched_topics=["graph/cal"]) as bus:
        sock = dealer(ctx, bus)
        deep = b"\x81\xa4text" + nested(5000)
        sock.send_multipart([b"SET", b"a/topic", header(), deep])
        sock.send_multipart([b"SET", b"b/topic", header(type_="Unknown"), b"\x81\xa1x" + nested(MAX_NESTING + 1)])
        sock.send_multipart([b"SET", b"c/topic", header(extra=nested(5000)), TEXT])
        errors = replies_until_pong(sock)
        assert [e[:2] for e in errors] == [[b"ERR", b"a/topic"], [b"ERR", b"b/topic"], [b"ERR", b"c/topic"]]
        assert b"nested deeper" in errors[0][2] and b"nested deeper" in errors[1][2]
        # a graph-latched topic published through the proxy: refused from the capture, the thread goes on
        assert bus.address is not None
        pub = ctx.socket(zmq.PUB)
        pub.linger = 0
        pub.connect(bus.address.pub)
        wait_until(lambda: (pub.send_multipart([b"graph/cal", header(latched=False), deep]), bus.latch_refused >= 4)[1],
                   10, "the deep captured value refused")
        sock.send_multipart([b"SET", b"a/topic", header(), TEXT])
        sock.send_multipart([b"GET", b"a/"])
        assert replies_until_pong(sock) == [[b"VAL", b"a/topic", header(), TEXT]]
        assert bus.internal_errors == 0


def test_a_full_cache_still_takes_a_later_clients_values(ctx: zmq.Context[zmq.Socket[bytes]]) -> None:
    with Bus(bus_spec("ipc")) as bus:
        flooder = dealer(ctx, bus)
        for i in range(4096 + 50):
            flooder.send_multipart([b"SET", f"junk/{i}".encode(), header(node="flood"), TEXT])
        assert replies_until_pong(flooder) == []  # it evicts only its own: nothing refused
        node = dealer(ctx, bus)
        node.send_multipart([b"SET", b"_palpa/srv/node/info", header(node="node"), TEXT])
        node.send_multipart([b"GET", b"_palpa/srv/"])
        assert replies_until_pong(node) == [[b"VAL", b"_palpa/srv/node/info", header(node="node"), TEXT]]
        assert len(bus.cached_topics()) == 4096 and bus.latch_refused == 0


def test_the_watcher_table_is_bounded_and_sets_still_reach_watchers(ctx: zmq.Context[zmq.Socket[bytes]],
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    with Bus(bus_spec("ipc")) as bus:
        flooder = dealer(ctx, bus)
        for i in range(MAX_WATCHES + 5000):
            flooder.send_multipart([b"GET", f"p/{i}/".encode()])
        flooder.send_multipart([b"GET", b"x" * 2000])
        errors = replies_until_pong(flooder)
        assert len(errors) == 1 and b"GET prefix of 2000 bytes" in errors[0][2]
        assert len(bus._watchers) == MAX_WATCHES and bus.watch_refused == 1
        assert "latch: watch refused" in caplog.text and "(1 so far)" in caplog.text  # its own count, not the SETs'
        watcher = dealer(ctx, bus)
        watcher.send_multipart([b"GET", b"robot/"])
        assert replies_until_pong(watcher) == []
        setter = dealer(ctx, bus)
        setter.send_multipart([b"SET", b"robot/cal", header(), TEXT])
        assert replies_until_pong(setter) == []
        assert watcher.poll(5000) and watcher.recv_multipart() == [b"VAL", b"robot/cal", header(), TEXT]


def test_a_request_whose_handling_raises_is_counted_and_the_thread_goes_on(
        ctx: zmq.Context[zmq.Socket[bytes]], monkeypatch: pytest.MonkeyPatch) -> None:
    with Bus(bus_spec("ipc")) as bus:
        def broken(topic: bytes, value: list[bytes]) -> str | None:
            raise ValueError("a bug not yet found")

        monkeypatch.setattr(bus._cache, "check", broken)
        sock = dealer(ctx, bus)
        sock.send_multipart([b"SET", b"a/topic", header(), TEXT])
        assert replies_until_pong(sock) == [] and bus.internal_errors == 1


def test_a_service_started_after_the_cache_was_flooded_is_announced_and_answers(
        ctx: zmq.Context[zmq.Socket[bytes]]) -> None:
    with Bus(bus_spec("ipc")) as bus:
        assert bus.address is not None
        flooder = dealer(ctx, bus)
        for i in range(4096 + 10):
            flooder.send_multipart([b"SET", f"junk/{i}".encode(), header(node="flood"), TEXT])
        replies_until_pong(flooder)
        assert len(bus.cached_topics()) == 4096  # full
        adder = Adder(name="adder", bus=bus.address, heartbeat_s=0)
        thread = threading.Thread(target=adder.spin, daemon=True)
        thread.start()
        try:
            with palpa.Node(name="caller", bus=bus.address, heartbeat_s=0) as caller:
                add = caller.client("math/add", AddRequest, AddReply)
                assert add.wait_for_service(10.0), "the service's announcement was not cached"
                assert add.call(AddRequest(a=1, b=2), timeout_s=10.0).total == 3
        finally:
            adder.request_shutdown()
            thread.join(5)
            adder.close(0)


_FLOODER = """
import sys, zmq
ctx = zmq.Context()
endpoint, header, n = sys.argv[1], bytes.fromhex(sys.argv[2]), int(sys.argv[3])
socks = []
for i in range(n):  # a connection per value: each holds less than the graph's node
    s = ctx.socket(zmq.DEALER)
    s.linger = 0
    s.connect(endpoint)
    s.send_multipart([b"SET", b"flood/%d" % i, header, bytes.fromhex(sys.argv[4])])
    socks.append(s)
refused = 0
for s in socks:
    s.send_multipart([b"PING", b"x"])
    while True:
        assert s.poll(20000), "no PONG"
        frames = s.recv_multipart()
        if frames[0] == b"PONG":
            break
        refused += frames[0] == b"ERR" and b"per peer" in frames[2]
print(refused)
"""


@pytest.mark.parametrize("max_entries", [200, 4096])
def test_a_process_spreading_a_flood_over_many_connections_evicts_only_its_own(
        ctx: zmq.Context[zmq.Socket[bytes]], max_entries: int) -> None:
    """200: the flood fills the cache and evicts its own values only (its peer holds the most, though each of its
    connections holds less than the node); 4096: it fits, but past the bound on connections per peer each further
    connection is refused."""
    with Bus(bus_spec("ipc"), latch_max_entries=max_entries) as bus:
        assert bus.address is not None
        node = dealer(ctx, bus)  # the graph's node, a process of its own: ten values on one connection
        for i in range(10):
            node.send_multipart([b"SET", f"node/{i}".encode(), header(node="node"), TEXT])
        assert replies_until_pong(node) == []
        n = MAX_CLIENTS_PER_PEER + 44
        done = subprocess.run([sys.executable, "-c", _FLOODER, bus.address.latch, header(node="flood").hex(), str(n),
                               TEXT.hex()], capture_output=True, text=True, timeout=120, check=False)
        assert done.returncode == 0, done.stderr
        refused = 0 if max_entries < n else 44  # connections whose values were all evicted no longer count
        assert int(done.stdout) == refused and bus.latch_refused == refused
        node.send_multipart([b"GET", b"node/"])
        assert [r[1] for r in replies_until_pong(node)] == [f"node/{i}".encode() for i in range(10)]
        assert len(bus.cached_topics()) == min(max_entries, 10 + MAX_CLIENTS_PER_PEER)
