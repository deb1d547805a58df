"""The bus's resources at their limits, as pure units (issue 39): bounded nesting on decode, the cache and watcher
tables bounded with an eviction rule that cannot lock the graph's own nodes out, throttled refusal logs. The same
over a real bus is in test_bus_limits_system.py."""

from __future__ import annotations

import logging
from pathlib import Path

import msgpack
import msgspec
import pytest

from palpa.errors import DecodeError
from palpa.lograte import LOG_INTERVAL_S, LogThrottle
from palpa.net.keys import ClientKeys
from palpa.net.latch import BUS_OWNER, LatchCache, OwnedTable, Watchers
from palpa.net.wire import MAX_NESTING, decode_any, decode_header, parse_envelope


def nested(depth: int, leaf: bytes = b"\x01") -> bytes:
    """``depth`` arrays inside each other around ``leaf``."""
    return b"\x91" * depth + leaf


def deep_map(depth: int) -> bytes:
    """A msgpack map whose field ``x`` holds ``depth - 1`` more levels: ``depth`` levels in all."""
    return b"\x81\xa1x" * depth + b"\x01"


def header(node: str = "n", type_: str = "Text", latched: bool = True, extra: bytes = b"") -> bytes:
    h: dict[str, object] = {"type": type_, "seq": 1, "stamp": 1, "node": node, "latched": latched}
    packed = bytes(msgpack.packb(h))
    if extra:  # one more (unknown) field, ``extra`` its raw value
        packed = bytes([packed[0] + 1]) + packed[1:] + b"\xa5extra" + extra
    return packed


def test_decode_any_refuses_nesting_past_the_limit_at_any_depth() -> None:
    assert decode_any(nested(MAX_NESTING)) is not None
    assert decode_any(deep_map(MAX_NESTING))
    for data in (nested(MAX_NESTING + 1), nested(MAX_NESTING, b"\x90"), deep_map(MAX_NESTING + 1),
                 nested(5000), nested(10**6)):
        with pytest.raises(DecodeError, match=f"nested deeper than {MAX_NESTING} levels"):
            decode_any(data)
    with pytest.raises(DecodeError, match="not msgpack"):
        decode_any(b"\xc1")


def test_strings_that_are_not_utf8_are_decode_errors_everywhere() -> None:
    bad = b"\x81\xa4text\xa1\x80"  # {"text": <one byte that is not UTF-8>}
    with pytest.raises(DecodeError, match="not msgpack"):
        decode_any(bad)
    with pytest.raises(DecodeError):
        decode_header(header(node="X").replace(b"\xa1X", b"\xa1\x80"))  # the node name is not UTF-8
    for type_ in ("Text", "NoSuchType"):
        why = LatchCache(frozenset()).check(b"t", [header(type_=type_), bad])
        assert why is not None and "not msgpack" in why


def test_typed_decodes_of_deep_input_raise_decode_errors_only() -> None:
    with pytest.raises(DecodeError):
        decode_header(header(extra=nested(5000)))  # a typed decode skips the unknown field, recursively
    with pytest.raises(DecodeError):
        parse_envelope([b"t", nested(5000), b"\x80"])  # an array: a batch header
    env = parse_envelope([b"t", msgpack.packb([msgpack.unpackb(header())]), nested(5000)])
    with pytest.raises(DecodeError):
        env.messages()


@pytest.mark.parametrize("type_", ["Text", "NoSuchType"])
def test_the_cache_refuses_a_deeply_nested_value(type_: str) -> None:
    cache = LatchCache(frozenset())
    ok = msgspec.msgpack.encode({"text": "x"})
    assert cache.check(b"t", [header(type_=type_), ok]) is None
    for payload in (b"\x81\xa4text" + nested(5000), b"\x81\xa5other" + nested(5000), deep_map(MAX_NESTING + 1)):
        why = cache.check(b"t", [header(type_=type_), payload])
        assert why is not None and f"nested deeper than {MAX_NESTING} levels" in why
    why = cache.check(b"t", [header(type_=type_, extra=nested(5000)), ok])
    assert why is not None and "bad envelope header" in why


def test_a_flooding_client_cannot_lock_later_clients_out_of_the_cache() -> None:
    table: OwnedTable[str, int] = OwnedTable(max_entries=10, max_bytes=1000)
    assert table.put("bus/keys", 0, 10, BUS_OWNER) == (None, [])
    for i in range(30):  # one client fills the table, then keeps going: it only evicts its own
        why, _ = table.put(f"flood/{i}", i, 10, b"flooder")
        assert why is None
    assert len(table) == 10 and "bus/keys" in table and "flood/29" in table and "flood/20" not in table
    for node in ("a", "b", "c"):  # nodes started later: room is made for them, from the flooder's oldest
        why, evicted = table.put(f"{node}/_svc", 1, 10, node.encode())
        assert why is None and [o for o, _ in evicted] == [b"flooder"]
    assert all(f"{n}/_svc" in table for n in "abc") and "flood/21" not in table and "flood/29" in table
    # a value that cannot fit beside what may not be evicted is refused and changes nothing
    before = dict(table.values)
    why, evicted = table.put("x", 3, 991, b"x")
    assert why is not None and "does not fit" in why and evicted == [] and table.values == before


def test_the_byte_bound_evicts_from_the_client_holding_the_most_bytes() -> None:
    table: OwnedTable[str, int] = OwnedTable(max_entries=100, max_bytes=100)
    for i in range(5):
        table.put(f"flood/{i}", i, 15, b"flooder")
    table.put("a/x", 0, 10, b"a")
    why, evicted = table.put("b/x", 0, 20, b"b")
    assert why is None and evicted == [(b"flooder", "flood/0")] and table.bytes == 90


def test_what_the_bus_itself_holds_is_never_evicted() -> None:
    table: OwnedTable[str, int] = OwnedTable(max_entries=4, max_bytes=1000)
    for i in range(3):
        table.put(f"bus/{i}", i, 1, BUS_OWNER)
    table.put("x/1", 0, 1, b"x")
    assert table.put("y/1", 0, 1, b"y") == (None, [(b"x", "x/1")])
    assert table.put("y/2", 0, 1, b"y") == (None, [(b"y", "y/1")])  # its own, not the bus's three
    assert all(f"bus/{i}" in table for i in range(3))


def test_a_flood_spread_over_many_connections_of_one_peer_evicts_only_that_peers_entries() -> None:
    table: OwnedTable[str, int] = OwnedTable(max_entries=20, max_bytes=10_000)
    for node in ("a", "b"):  # the graph's nodes: a few entries each, one connection, a peer (process) each
        for i in range(3):
            assert table.put(f"{node}/{i}", i, 10, node.encode(), f"pid-{node}".encode()) == (None, [])
    for i in range(100):  # one process, a connection per entry: under the old per-connection rule a node's
        why, evicted = table.put(f"flood/{i}", i, 10, f"conn-{i}".encode(), b"pid-flooder")  # three were the most
        assert why is None and all(o.startswith(b"conn-") for o, _ in evicted)
    assert all(f"{n}/{i}" in table for n in "ab" for i in range(3)) and len(table) == 20
    why, evicted = table.put("c/0", 0, 10, b"c", b"pid-c")  # a node started later gets room from the flooder
    assert why is None and evicted == [(b"conn-86", "flood/86")]
    # by bytes too: the flooder's peer holds the most bytes, though each of its connections holds little
    small: OwnedTable[str, int] = OwnedTable(max_entries=100, max_bytes=100)
    small.put("a/x", 0, 30, b"a", b"pid-a")
    for i in range(7):
        small.put(f"flood/{i}", i, 10, f"conn-{i}".encode(), b"pid-flooder")
    assert small.put("b/x", 0, 20, b"b", b"pid-b") == (None, [(b"conn-0", "flood/0"), (b"conn-1", "flood/1")])


def test_within_one_peer_the_client_holding_the_most_goes_first() -> None:
    # every local client is one peer on a loopback tcp bus: there the old per-connection rule still holds
    table: OwnedTable[str, int] = OwnedTable(max_entries=10, max_bytes=1000)
    for i in range(3):
        table.put(f"node/{i}", i, 1, b"node", b"127.0.0.1")
    for i in range(20):
        why, evicted = table.put(f"flood/{i}", i, 1, b"flooder", b"127.0.0.1")
        assert why is None and all(o == b"flooder" for o, _ in evicted)
    assert all(f"node/{i}" in table for i in range(3))


def test_a_peer_holds_entries_through_a_bounded_number_of_connections() -> None:
    table: OwnedTable[str, int] = OwnedTable(max_entries=100, max_bytes=1000, max_clients_per_peer=3)
    for i in range(3):
        assert table.put(f"f/{i}", i, 1, f"conn-{i}".encode(), b"pid-f") == (None, [])
    assert table.put("f/0", 5, 1, b"conn-0", b"pid-f") == (None, [])  # a client it has: as before
    before = dict(table.values)
    why, evicted = table.put("f/3", 3, 1, b"conn-3", b"pid-f")
    assert why is not None and "pid-f already uses 3 connections here (at most 3 per peer)" in why
    assert evicted == [] and table.values == before and table.refused_clients == 1
    assert table.put("n/0", 0, 1, b"node", b"pid-n") == (None, [])  # another peer is not concerned
    table.pop("f/2")  # a connection holding nothing no longer counts
    assert table.put("f/3", 3, 1, b"conn-3", b"pid-f") == (None, [])
    watchers = Watchers(max_watches=100, max_bytes=10_000)
    watchers._table.max_clients_per_peer = 2
    assert watchers.add(b"x/", b"c1", b"p") is None and watchers.add(b"y/", b"c2", b"p") is None
    assert "at most 2 per peer" in (watchers.add(b"z/", b"c3", b"p") or "")
    assert watchers.matching(b"z/1") == []


def test_the_latch_cache_puts_by_owner_and_reports_evictions() -> None:
    cache = LatchCache(frozenset(), max_entries=3)
    for i in range(3):
        assert cache.put(f"f/{i}".encode(), [b"h", b"p"], b"flooder") == (None, [])
    assert cache.put(b"node/x", [b"h", b"p"], b"node") == (None, [b"f/0"])
    assert sorted(cache.values) == [b"f/1", b"f/2", b"node/x"]


def test_watchers_are_bounded_and_found_by_prefix() -> None:
    watchers = Watchers(max_watches=100, max_bytes=10_000)
    for i in range(1000):  # a million distinct prefixes would do the same: at most 100 kept
        assert watchers.add(f"junk/{i}/".encode(), b"flooder") is None
    assert len(watchers) == 100 and watchers.evicted == 900
    assert watchers.add(b"robot/", b"node") is None and watchers.add(b"", b"recorder") is None
    assert sorted(watchers.matching(b"robot/pose")) == [(b"", b"recorder"), (b"robot/", b"node")]
    assert watchers.matching(b"junk/999/x") == [(b"", b"recorder"), (b"junk/999/", b"flooder")]
    assert watchers.matching(b"junk/5/x") == [(b"", b"recorder")]  # evicted long ago
    watchers.discard(b"robot/", b"node")
    assert watchers.matching(b"robot/pose") == [(b"", b"recorder")]


def test_the_log_throttle_counts_everything_and_logs_one_line_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    throttle = LogThrottle(logging.getLogger("t"), interval_s=5.0, now=lambda: now[0])
    caplog.set_level(logging.WARNING)
    for i in range(1000):
        now[0] = i * 0.01  # 10 s in all
        throttle.event("refused", logging.WARNING, "refused %d", i)
    assert throttle.counts == {"refused": 1000} and throttle.lines == 2
    assert [r.getMessage() for r in caplog.records] == ["refused 0", "refused 500 (and 499 more like it in the "
                                                        "last 5 s)"]


def test_unauthenticated_handshakes_are_all_counted_and_logged_once_per_interval(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    clients = ClientKeys(tmp_path)
    now = [0.0]
    clients._throttle._now = lambda: now[0]
    caplog.set_level(logging.WARNING, logger="palpa.net.bus.auth")
    for i in range(20_000):  # each a key of its own, as a scanner trying keys would send
        assert not clients.callback("*", f"{i:040d}".encode())
    now[0] = LOG_INTERVAL_S
    assert not clients.callback("*", b"k" * 40)
    assert clients.refused == 20_001
    lines = [r.getMessage() for r in caplog.records if "CURVE: refused a client" in r.getMessage()]
    assert len(lines) == 2 and "(and 19999 more like it in the last 5 s)" in lines[1]
