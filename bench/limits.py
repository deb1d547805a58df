"""Memory and time at the limits of issue 39 (items 8 and 9), before and after bounding them. Not a test: it prints
numbers. Runs against whatever ``palpa`` is importable (PYTHONPATH=<a checkout of main> for the before).

    python bench/limits.py watchers [N_GETS]      # N distinct-prefix GETs, then 200 SETs: bus RSS and SET time
    python bench/limits.py latched [N] [MIB]      # N latched publishers of MIB MiB each: recorder RSS
    python bench/limits.py publishers [N]         # N publisher names on one topic: recorder RSS

Each case runs in a fresh process (RSS is that process's, measured with psutil)."""

from __future__ import annotations

import gc
import sys
import tempfile
import time
from pathlib import Path

import msgpack
import psutil
import zmq

from palpa.net.address import BusAddress
from palpa.net.bus import Bus
from palpa.net.wire import Header, encode_header
from palpa.record.recorder import Recorder
from palpa.testing import NodeHarness


def rss_mb() -> float:
    gc.collect()
    return psutil.Process().memory_info().rss / 1e6


def sync(sock: zmq.Socket[bytes]) -> None:
    """Until the bus has answered everything sent before (PING -> PONG comes after every earlier reply)."""
    sock.send_multipart([b"PING", b"t"])
    while sock.recv_multipart() != [b"PONG", b"t"]:
        pass


def watchers(n_gets: int) -> None:
    base = tempfile.mkdtemp(prefix="pl-")
    with Bus(BusAddress.parse(f"ipc://{base}/b")) as bus:
        assert bus.address is not None
        ctx = zmq.Context.instance()
        sock = ctx.socket(zmq.DEALER)
        sock.linger = 0
        sock.connect(bus.address.latch)
        sync(sock)
        before = rss_mb()
        t0 = time.perf_counter()
        for i in range(n_gets):
            sock.send_multipart([b"GET", b"junk/%d/" % i])
            if i % 10_000 == 9_999:
                sync(sock)  # do not let the socket's queue hold the backlog
        sync(sock)
        t_gets = time.perf_counter() - t0
        grown = rss_mb() - before
        header = encode_header(Header(type="Text", seq=1, stamp=1, node="b", latched=True))
        value = bytes(msgpack.packb({"text": "x"}))
        t0 = time.perf_counter()
        for i in range(200):
            sock.send_multipart([b"SET", b"robot/%d" % i, header, value])
        sync(sock)
        t_sets = time.perf_counter() - t0
        held = len(bus._watchers)
        print(f"watchers: {n_gets} GETs in {t_gets:.1f} s ({held} watches held), bus RSS +{grown:.0f} MB; 200 SETs "
              f"then took {t_sets:.3f} s")
        sock.close(0)


def latched(n: int, mib: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        h = NodeHarness(Recorder, {"output": str(Path(tmp) / "r.mcap")})
        before = rss_mb()
        for i in range(n):
            payload = bytes(msgpack.packb({"text": f"{i}" + "x" * int(mib * 2**20)}))  # each its own bytes
            h.publish_raw([b"cal/%d" % i, encode_header(Header(type="Text", seq=1, stamp=1, node=f"p{i}",
                                                               latched=True)), payload])
            h.raw.clear()  # the harness's own copy of what went by is not the recorder's
        grown = rss_mb() - before
        print(f"latched: {n} publishers x {mib:g} MiB latched values: recorder RSS +{grown:.0f} MB")
        h.close()


def publishers(n: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        h = NodeHarness(Recorder, {"output": str(Path(tmp) / "r.mcap"), "topics": ["nothing-recorded"]})
        # the recorder records nothing here: what grows is its per-publisher sequence state alone
        h._probe.close(0)
        h.nodes[0].subscribe_raw("chatter", lambda raw: None)
        value = bytes(msgpack.packb({"text": "x"}))
        before = rss_mb()
        for i in range(n):
            h.bus._route([b"chatter", encode_header(Header(type="Text", seq=1, stamp=1, node=f"name-{i}")), value],
                         False)
            h.nodes[0].spin_once(0)
        grown = rss_mb() - before
        print(f"publishers: {n} publisher names: recorder RSS +{grown:.0f} MB")
        h.nodes[0].close(0)


if __name__ == "__main__":
    case = sys.argv[1]
    args = [float(a) for a in sys.argv[2:]]
    if case == "watchers":
        watchers(int(args[0]) if args else 1_000_000)
    elif case == "latched":
        latched(int(args[0]) if args else 300, args[1] if len(args) > 1 else 2.0)
    elif case == "publishers":
        publishers(int(args[0]) if args else 200_000)
    else:
        raise SystemExit(__doc__)
