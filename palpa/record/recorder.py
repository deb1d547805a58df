"""The recorder node: every envelope on the bus (or the topics asked for) into MCAP, payload bytes untouched.

Run it as ``palpa record ...``, ``palpa run palpa.record.recorder:Recorder -p output=run.mcap``, or from a
launch file's ``record:`` section. SIGINT/SIGTERM finalise the file (summary, indexes, drop counts); a SIGKILL
loses at most the last ``flush_period_s`` (0.5 s) of messages, and ``palpa bag recover`` rebuilds the index.

What gets recorded: topics matching ``topics`` (regexes over the whole name; empty = all) and not ``exclude``.
Runtime topics (``_palpa/...``) only when a pattern starting with ``_palpa`` names them, except ``_palpa/log`` and
``_palpa/params`` (runtime parameter changes), which are always kept (a run's log lines and retunings are part of
its record; exclude them explicitly to drop them). Service requests and replies (``NAME/request``,
``NAME/reply/CLIENT``) are ordinary topics and recorded as such. Heartbeats
are not recorded by default but feed the node list stored in the file.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import mcap
import msgspec

import palpa
from palpa.lograte import LogThrottle
from palpa.net.wire import DECODE_ERRORS
from palpa.node.node import Node, RawMessage
from palpa.node.params import convert_params
from palpa.node.params_runtime import PARAMS_TOPIC
from palpa.record.format import (
    BLOBS_SCHEMA,
    BLOBS_SCHEMA_NAME,
    BLOBS_TOPIC_PREFIX,
    LAUNCH_ATTACHMENT,
    MD_DROPS,
    MD_NODES,
    MD_RECORDING,
    MD_REFUSED,
    MESSAGE_ENCODING,
    META_BLOBS_OF,
    META_LATCHED,
    META_PUBLISHER,
    META_SCHEMA,
    META_SEQ_BASE,
    META_TYPE,
    SCHEMA_ENCODING,
    BagError,
    TopicFilter,
    dumps,
    schema_bytes,
    split_path,
)
from palpa.record.lastvalues import LastValues
from palpa.record.recorder_params import RecorderParams, check_params, prepare_output
from palpa.record.writer import MAX_CHANNELS, BagWriter
from palpa.runtime_msgs import HEARTBEAT_TOPIC, LOG_TOPIC, Heartbeat

__all__ = ["MAX_LATCHED_BYTES", "RESERVED_CHANNELS", "RecorderParams", "Recorder"]

RESERVED_CHANNELS = 1024
"""Of a file's MAX_CHANNELS channels, the last this many go only to publishers the recorder has heard a heartbeat
from (the graph's own nodes), so a flood of invented publisher names or sequence epochs cannot lock them out."""
MAX_LATCHED_BYTES = 64 * 2**20
"""Bytes of last latched values the recorder keeps to open each split piece with; past it the least recently
updated values are forgotten (logged and counted in ``palpa.refused``)."""

_ChannelKey = tuple[str, str, str, bool, int]  # topic, publisher, type, latched, sequence epoch (seq >> 32)
_blobs_encoder = msgspec.msgpack.Encoder()
_any_decoder = msgspec.msgpack.Decoder()


def _well_formed(payload: bytes) -> bool:
    """Whether a payload is what every palpa message is: one complete msgpack map."""
    if not payload or not (payload[0] & 0xF0 == 0x80 or payload[0] in (0xDE, 0xDF)):
        return False
    try:
        _any_decoder.decode(payload)
    except DECODE_ERRORS:  # not msgpack, a string not UTF-8, or nested past the interpreter's stack
        return False
    return True


_COUNTERS = ("received", "gaps", "duplicates", "restarts", "decode_errors")


class Recorder(Node):
    """Writes bus traffic to ``output`` (MCAP). See the module docstring for what is recorded."""

    Params = RecorderParams
    params: RecorderParams

    def __init__(self, name: str | None = None, params: Mapping[str, Any] | RecorderParams | None = None,
                 **kwargs: Any) -> None:
        kwargs["sim_clock"] = False  # its flush timer must run on wall time even in a sim-clock graph
        where = f"node {name or 'recorder'!r}"
        checked = convert_params(RecorderParams, params, where=where)
        self._check(checked, where)  # before any socket: a bad file or parameter fails at once, bus or not
        super().__init__(name, checked, **kwargs)

    def _check(self, p: RecorderParams, where: str) -> None:
        self._launch_text = check_params(p, where)
        self._filter = TopicFilter(p.topics, p.exclude, always=(LOG_TOPIC, PARAMS_TOPIC))
        self._splitting = p.split_size_mb > 0 or p.split_duration_s > 0
        self._split_bytes = int(p.split_size_mb * 1e6) if p.split_size_mb > 0 else 1 << 62
        prepare_output(p, self._splitting)

    def setup(self) -> None:
        p = self.params
        self._record_started_ns = time.time_ns()  # not Node's uptime origin
        self._host = socket.gethostname()
        self._ids: dict[_ChannelKey, int] = {}
        self._blob_ids: dict[int, int] = {}
        self._schema_ids: dict[str, int] = {}
        self._schema_cache: dict[str, bytes | None] = {}
        self._latched: LastValues[_ChannelKey] = LastValues(MAX_LATCHED_BYTES)
        self._throttle = LogThrottle(self.log, now=lambda: self.clock.now_ns() / 1e9)
        self._refused: dict[str, int] = {}
        """Refusals (and forgotten latched values) of the open file, by reason; written as palpa.refused."""
        self.refused: dict[str, int] = {}
        """What was refused (or forgotten) so far, by reason, over all files (each file's own in palpa.refused)."""
        self._bus_latched: set[str] = set()
        self._nodes: dict[str, str] = {}
        self._nodes_dirty = False
        self._failed = False
        self.files: list[Path] = []
        self.recorded = 0
        self._file_index = 0
        self._counter_base: dict[str, dict[str, int]] = {}
        self._writer = self._open_file()
        self.subscribe_raw("", self._on_raw, topics=self._filter)  # a lockstep's ticks cost nothing when excluded
        self.subscribe(HEARTBEAT_TOPIC, Heartbeat, self._on_heartbeat)
        self.timer(p.flush_period_s, self._tick)
        self.log.info("recording to %s", self._writer.path)

    # -- files -------------------------------------------------------------------------------------------
    def _open_file(self) -> BagWriter:
        self._file_index += 1
        out = Path(self.params.output)
        path = split_path(out, self._file_index) if self._splitting else out
        writer = BagWriter(path, compression=self.params.compression, fsync=self.params.fsync,
                           overwrite=self.params.force,
                           library=f"palpa/{palpa.__version__}; mcap-python/{mcap.__version__}")
        self._writer = writer
        self.files.append(path)
        self._ids = {}
        self._blob_ids = {}
        self._schema_ids = {}
        self._opened_ns = time.time_ns()
        self._split_due_ns = (self.clock.now_ns() + int(self.params.split_duration_s * 1e9)
                              if self.params.split_duration_s > 0 else None)
        writer.add_metadata(MD_RECORDING, {
            "palpa_version": palpa.__version__,
            "mcap_library": mcap.__version__,
            "host": self._host,
            "recorder": self.name,
            "started_ns": str(self._record_started_ns),
            "file_opened_ns": str(self._opened_ns),
            "file_index": str(self._file_index),
            "output": str(out),
            "params": dumps(msgspec.to_builtins(self.params)),
        })
        if self._launch_text:
            writer.add_attachment(LAUNCH_ATTACHMENT, "application/yaml", self._launch_text,
                                  log_time=self._opened_ns)
        if self._nodes:
            writer.add_metadata(MD_NODES, self._nodes)
        self._counter_base = {t: s.as_dict() for t, s in self.counters().items()}
        self._refused = {}
        # a split piece must stand alone: the last value of every latched topic opens it
        for key, raw in self._latched.items():
            cid = self._channel_for(key)
            if cid:
                if raw.blobs:
                    self._write_blobs(cid, raw, self._opened_ns)
                writer.add_message(cid, self._opened_ns, raw.header.stamp, raw.header.seq & 0xFFFF_FFFF,
                                   raw.payload)
        writer.flush()
        return writer

    def _close_file(self) -> None:
        w = self._writer
        if w.finished:
            return
        drops: dict[str, str] = {}
        for topic, stats in self.counters().items():
            if not self._filter(topic):
                continue
            base = self._counter_base.get(topic, {})
            now = stats.as_dict()
            delta = {k: now[k] - base.get(k, 0) for k in _COUNTERS}
            if any(delta.values()):
                drops[topic] = dumps(delta)
        w.add_metadata(MD_DROPS, drops)
        w.add_metadata(MD_REFUSED, {k: str(v) for k, v in sorted(self._refused.items())})
        w.add_metadata(MD_NODES, self._nodes)
        w.finish()
        self.recorded += w.message_count

    def _roll(self) -> None:
        self._close_file()
        self._open_file()
        self.log.info("split: now recording to %s", self._writer.path)

    # -- channels ----------------------------------------------------------------------------------------
    def _schema_id(self, type_name: str) -> int:
        sid = self._schema_ids.get(type_name)
        if sid is not None:
            return sid
        if type_name not in self._schema_cache:
            data = self._schema_cache[type_name] = schema_bytes(type_name)
            if data is None:
                self.log.warning("message type %r is not importable here: its channels are recorded without "
                                 "a schema (set PALPA_MESSAGES to the module that defines it)", type_name)
        data = self._schema_cache[type_name]
        sid = self._writer.register_schema(type_name, SCHEMA_ENCODING, data) if data else 0
        self._schema_ids[type_name] = sid
        return sid

    def _channel_for(self, key: _ChannelKey) -> int | None:
        """The channel id of ``key`` (registered now if new); 0 for a topic not recorded; None when the file has no
        room for it and a blob channel it may need within MAX_CHANNELS (less RESERVED_CHANNELS for a publisher
        not heard in heartbeats)."""
        topic, node, type_name, latched, epoch = key
        if not self._filter(topic):
            self._ids[key] = 0
            return 0
        room = MAX_CHANNELS - len(self._writer.channels) - (0 if node in self._nodes else RESERVED_CHANNELS)
        if room < 2:  # the channel and, should its messages carry blobs, their companion channel
            return None
        sid = self._schema_id(type_name)
        md = {META_TYPE: type_name, META_PUBLISHER: node, META_LATCHED: "true" if latched else "false"}
        if epoch:
            md[META_SEQ_BASE] = str(epoch << 32)
        if not sid:
            md[META_SCHEMA] = f"none: type {type_name!r} was not importable by the recorder"
        cid = self._writer.register_channel(topic, MESSAGE_ENCODING, sid, md)
        self._ids[key] = cid
        return cid

    def _refuse(self, reason: str, text: str, *args: object) -> None:
        """Count one message (or latched value) not kept, for the file's palpa.refused, and log it (throttled)."""
        self._refused[reason] = self._refused.get(reason, 0) + 1
        self.refused[reason] = self.refused.get(reason, 0) + 1
        self._throttle.event(reason, logging.WARNING, text, *args)

    def _write_blobs(self, cid: int, raw: RawMessage, log_time: int) -> None:
        bid = self._blob_ids.get(cid)
        if bid is None:
            sid = self._schema_ids.get(BLOBS_SCHEMA_NAME)
            if sid is None:
                sid = self._schema_ids[BLOBS_SCHEMA_NAME] = self._writer.register_schema(
                    BLOBS_SCHEMA_NAME, SCHEMA_ENCODING, BLOBS_SCHEMA)
            bid = self._blob_ids[cid] = self._writer.register_channel(
                BLOBS_TOPIC_PREFIX + raw.topic, MESSAGE_ENCODING, sid, {META_BLOBS_OF: str(cid)})
        self._writer.add_message(bid, log_time, raw.header.stamp, raw.header.seq & 0xFFFF_FFFF,
                                 _blobs_encoder.encode([bytes(b) for b in raw.blobs]))

    # -- the hot path ------------------------------------------------------------------------------------
    def _on_raw(self, raw: RawMessage) -> None:
        topic, h, payload, blobs, cached, recv_ns = raw.topic, raw.header, raw.payload, raw.blobs, raw.from_cache, \
            raw.recv_ns
        seq = h.seq
        if h.stamp < 0:  # MCAP's publish time is a uint64 (and msgpack carries nothing above one)
            self._refuse("stamp_out_of_range", "refused a message on %r from %r: stamp %d ns is before 1970 (MCAP "
                         "times are 0..2**64-1 ns)", topic, h.node, h.stamp)
            return
        key = (topic, h.node, h.type, h.latched, seq >> 32)
        cid = self._ids.get(key)
        try:
            if cid is None:
                if self._failed:
                    return
                cid = self._channel_for(key)
                if cid is None:
                    self._refuse("channel_limit", "refused a message on %r from %r: %s holds %d channels, the most "
                                 "it takes (%d, the last %d kept for nodes with heartbeats)", topic, h.node,
                                 self._writer.path, len(self._writer.channels), MAX_CHANNELS, RESERVED_CHANNELS)
                    return
            if not cid:
                return
            w = self._writer
            if blobs and cid not in self._blob_ids and len(w.channels) >= MAX_CHANNELS:
                self._refuse("channel_limit", "refused a message with blobs on %r from %r: %s has no room for its "
                             "blob channel (%d channels)", topic, h.node, w.path, MAX_CHANNELS)
                return
            if blobs:  # before the message, so a reader has them when the message comes
                self._write_blobs(cid, raw, recv_ns)
            w.add_message(cid, recv_ns, h.stamp, seq & 0xFFFF_FFFF, payload)
            if not _well_formed(payload):  # recorded as the wire carried it, and counted so the file says so
                self.count_bad_raw(topic)
            if h.latched or cached or (self._bus_latched and topic in self._bus_latched):
                if cached:
                    self._bus_latched.add(topic)
                for gone in self._latched.put(key, raw):
                    self._refuse("latched_forgotten", "latched values over %d bytes: forgot the last value of %r "
                                 "from %r (later split pieces do not start with it)", MAX_LATCHED_BYTES, gone[0],
                                 gone[1])
            if w.written >= self._split_bytes:
                self._roll()
        except (OSError, BagError) as exc:
            self._fail(exc)

    def _on_heartbeat(self, hb: Heartbeat) -> None:
        text = dumps({"pid": hb.pid, "host": hb.host, "publishes": hb.publishes, "subscribes": hb.subscribes})
        if self._nodes.get(hb.node) != text:
            self._nodes[hb.node] = text
            self._nodes_dirty = True

    def _tick(self) -> None:
        if self._failed:
            return
        try:
            if self._nodes_dirty:
                self._nodes_dirty = False
                self._writer.add_metadata(MD_NODES, self._nodes)
            self._writer.flush()
            due = self._split_due_ns is not None and self.clock.now_ns() >= self._split_due_ns
            if due or self._writer.written >= self._split_bytes:
                self._roll()
        except (OSError, BagError) as exc:
            self._fail(exc)

    def _fail(self, exc: Exception) -> None:
        self._failed = True
        self._ids = {}
        self.log.error("recording to %s failed: %s; stopping (the file is recoverable with "
                       "`palpa bag recover`)", self._writer.path, exc)
        with contextlib.suppress(OSError):
            self._writer.abandon()
        self.request_shutdown(1)

    # -- lifecycle ---------------------------------------------------------------------------------------
    def spin(self) -> None:
        """Spin until asked to stop, then take what already arrived (bounded) before the file is closed."""
        super().spin()
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and not self._failed:
            before = (self._file_index, self._writer.size)
            self.spin_once(0.05)
            if (self._file_index, self._writer.size) == before:
                break

    def on_shutdown(self) -> None:
        if self._failed:
            return
        try:
            self._close_file()
        except (OSError, BagError) as exc:
            self._fail(exc)
            return
        lost = any(d["gaps"] for d in self.drops().values()) or bool(self.refused)
        (self.log.warning if lost else self.log.info)("%s", self.report())

    def drops(self) -> dict[str, dict[str, int]]:
        """Counters of every recorded topic that lost messages, saw a publisher restart or a bad envelope."""
        out = {}
        for topic, stats in self.counters().items():
            d = stats.as_dict()
            if self._filter(topic) and (d["gaps"] or d["decode_errors"] or d["restarts"]):
                out[topic] = d
        return out

    def report(self) -> str:
        """One line: messages and files, then the topics that lost messages (sequence gaps), if any."""
        files = ", ".join(str(f) for f in self.files)
        text = f"recorded {self.recorded} messages in {len(self.files)} file(s): {files}"
        counters = sorted(self.drops().items())
        lost = [f"{t}: {d['gaps']} missing" for t, d in counters if d["gaps"]]
        text += ("; DROPS " + "; ".join(lost)) if lost else "; no drops (no sequence gaps)"
        other = [f"{t}: " + ", ".join(f"{d[k]} {k.replace('_', ' ')}" for k in ("restarts", "decode_errors") if d[k])
                 for t, d in counters if d["restarts"] or d["decode_errors"]]
        text += ("; also " + "; ".join(other) if other else "")
        if self.refused:
            text += "; REFUSED " + ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in
                                            sorted(self.refused.items())) + " (see docs/limits.md)"
        return text
