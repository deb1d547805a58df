"""``palpa bag info``: what a recording holds, read from the file alone (no message code needed).

Finished files answer from their summary section (fast); a file without one (a killed recorder) is scanned and
its drops are counted from the recorded sequence numbers.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, ChunkIndex, McapRecord, Metadata

from palpa.net.wire import SequenceTracker, TopicStats
from palpa.record.format import MD_DROPS, MD_NODES, MD_RECORDING, MD_RECOVERY, META_SCHEMA, BagError
from palpa.record.reader import channel_info, iter_file

__all__ = ["bag_info", "format_info"]

_INDEX_HEAD = struct.Struct("<BQHI")


def _file_info(path: Path) -> dict[str, Any]:
    """Per-file facts: channels with counts, times, metadata (last record of each name), attachments."""
    metadata: dict[str, dict[str, str]] = {}
    attachments: list[dict[str, Any]] = []
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    spans: dict[int, tuple[int, int]] = {}
    start = end = 0
    finalized = True
    damage = ""
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary() if _has_footer(fh) else None
            if summary is not None and summary.statistics is not None:
                stats = summary.statistics
                channels = dict(summary.channels)
                counts = dict(stats.channel_message_counts)
                start, end = stats.message_start_time, stats.message_end_time
                spans = _channel_spans(fh, summary.chunk_indexes)
                for md in reader.iter_metadata():
                    metadata[md.name] = md.metadata
                for att in reader.iter_attachments():
                    attachments.append({"name": att.name, "media_type": att.media_type, "bytes": len(att.data)})
            else:
                finalized = False
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - a damaged summary: fall back to scanning
        finalized = False
        damage = str(exc)
    drops: dict[str, dict[str, int]] | None = None
    if not finalized:
        tracker = SequenceTracker()
        scanned: dict[str, TopicStats] = {}

        def on_record(rec: McapRecord) -> None:
            if isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                metadata[rec.name] = rec.metadata
            elif isinstance(rec, Attachment):
                attachments.append({"name": rec.name, "media_type": rec.media_type, "bytes": len(rec.data)})

        def on_damage(text: str) -> None:
            nonlocal damage
            damage = text

        for m in iter_file(path, on_damage=on_damage, on_record=on_record):
            counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
            first, last = spans.get(m.channel_id, (m.log_time, m.log_time))
            spans[m.channel_id] = (min(first, m.log_time), max(last, m.log_time))
            start = m.log_time if not start else min(start, m.log_time)
            end = max(end, m.log_time)
            tracker.observe(m.topic, m.node, m.seq, scanned.setdefault(m.topic, TopicStats()))
        drops = {t: s.as_dict() for t, s in scanned.items()}
    if drops is None:
        drops = {t: json.loads(v) for t, v in metadata.get(MD_DROPS, {}).items()}
    return {"path": str(path), "bytes": path.stat().st_size, "finalized": finalized, "damage": damage,
            "start_ns": start, "end_ns": end, "channels": channels, "counts": counts, "spans": spans,
            "metadata": metadata,
            "attachments": attachments, "drops": drops}


def _channel_spans(fh: Any, chunk_indexes: Sequence[ChunkIndex]) -> dict[int, tuple[int, int]]:
    """First and last log time per channel, from the first and last entry of each Message Index record
    (entries are in write order, which is log-time order for files palpa writes)."""
    spans: dict[int, tuple[int, int]] = {}
    for ci in chunk_indexes:
        for cid, offset in ci.message_index_offsets.items():
            fh.seek(offset)
            opcode, _length, _cid, nbytes = _INDEX_HEAD.unpack(fh.read(_INDEX_HEAD.size))
            if opcode != Opcode.MESSAGE_INDEX or nbytes < 16:
                continue
            (first,) = struct.unpack("<Q", fh.read(8))
            fh.seek(offset + _INDEX_HEAD.size + nbytes - 16)
            (last,) = struct.unpack("<Q", fh.read(8))
            lo, hi = spans.get(cid, (first, last))
            spans[cid] = (min(lo, first, last), max(hi, first, last))
    return spans


def _has_footer(fh: Any) -> bool:
    fh.seek(-8, os.SEEK_END)
    ok = bool(fh.read(8) == b"\x89MCAP0\r\n")
    fh.seek(0)
    return ok


def bag_info(paths: Sequence[Path]) -> dict[str, Any]:
    """Everything ``bag info`` prints, as plain data (also ``--json``)."""
    files = [_file_info(p) for p in paths]
    topics: dict[str, dict[str, Any]] = {}
    faults: dict[str, int] = {}
    for f in files:
        for cid, ch in f["channels"].items():
            info = channel_info(ch)
            if info.blobs_of:
                continue
            t = topics.setdefault(ch.topic, {"types": [], "publishers": [], "messages": 0, "latched": False,
                                             "schema": True, "drops": {"gaps": 0, "restarts": 0,
                                                                       "decode_errors": 0}})
            if info.type and info.type not in t["types"]:
                t["types"].append(info.type)
            if info.node and info.node not in t["publishers"]:
                t["publishers"].append(info.node)
            t["messages"] += f["counts"].get(cid, 0)
            if info.type == "ServiceFault":
                faults[ch.topic] = faults.get(ch.topic, 0) + f["counts"].get(cid, 0)
            if cid in f["spans"]:
                lo, hi = f["spans"][cid]
                t["first_ns"] = min(t.get("first_ns", lo), lo)
                t["last_ns"] = max(t.get("last_ns", hi), hi)
            t["latched"] = t["latched"] or info.latched
            if ch.schema_id == 0:
                t["schema"] = False
                t["schema_note"] = ch.metadata.get(META_SCHEMA, "no schema")
        for topic, d in f["drops"].items():
            if topic in topics:
                for k in ("gaps", "restarts", "decode_errors"):
                    topics[topic]["drops"][k] += int(d.get(k, 0))
    starts = [f["start_ns"] for f in files if f["start_ns"]]
    start = min(starts) if starts else 0
    end = max((f["end_ns"] for f in files), default=0)
    duration = (end - start) / 1e9 if start else 0.0
    for t in topics.values():
        span = (t.get("last_ns", 0) - t.get("first_ns", 0)) / 1e9
        t["rate_hz"] = (t["messages"] - 1) / span if t["messages"] > 1 and span > 0 else 0.0
    nodes: dict[str, Any] = {}
    recording: dict[str, str] = {}
    for f in files:
        for name, text in f["metadata"].get(MD_NODES, {}).items():
            nodes[name] = json.loads(text)
        recording = recording or f["metadata"].get(MD_RECORDING, {})
    return {
        "files": [{"path": f["path"], "bytes": f["bytes"], "finalized": f["finalized"], "damage": f["damage"],
                   "recovered": f["metadata"].get(MD_RECOVERY)} for f in files],
        "start_ns": start, "end_ns": end, "duration_s": duration,
        "messages": sum(t["messages"] for t in topics.values()),
        "topics": dict(sorted(topics.items())),
        "nodes": dict(sorted(nodes.items())),
        "services": _services(topics, faults),
        "recording": recording,
        "attachments": [a for f in files for a in f["attachments"]],
    }


def _services(topics: dict[str, dict[str, Any]], faults: dict[str, int]) -> dict[str, dict[str, Any]]:
    """Service calls in the recording, from the request and reply topics (palpa.node.service): per service, the
    request and response types, requests, replies, failed replies and callers."""
    out: dict[str, dict[str, Any]] = {}
    for topic, t in topics.items():
        name, sep, client = topic.rpartition("/reply/")
        if not sep:
            name, sep, rest = topic.rpartition("/request")
            if not sep or rest:
                continue
            client = ""
        s = out.setdefault(name, {"request": "?", "response": "?", "requests": 0, "replies": 0, "faults": 0,
                                  "callers": 0})
        if client:
            s["replies"] += t["messages"]
            s["faults"] += faults.get(topic, 0)
            s["callers"] += 1
            s["response"] = "/".join(x for x in t["types"] if x != "ServiceFault") or s["response"]
        else:
            s["requests"] += t["messages"]
            s["request"] = "/".join(t["types"]) or "?"
    return {k: v for k, v in sorted(out.items()) if v["requests"] or v["callers"]}


def _when(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC" if ns else "-"


def _shown(text: object) -> str:
    """A name from the file as it may be printed: control and other non-printable characters escaped (a topic
    or node name is whatever a peer sent; a raw escape sequence would rewrite the operator's terminal)."""
    s = str(text)
    return s if s.isprintable() else "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                                             for c in s)


def format_info(info: dict[str, Any]) -> str:
    """The human-readable report (every name from the file escaped, see :func:`_shown`)."""
    lines = []
    for f in info["files"]:
        state = "complete" if f["finalized"] else "NOT FINALIZED (run `palpa bag recover`)"
        if f["recovered"]:
            state += f", recovered from {f['recovered'].get('source', '?')}"
        lines.append(f"file:        {f['path']}  ({f['bytes'] / 1e6:.2f} MB, {state})")
        if f["damage"]:
            lines.append(f"             damage: {f['damage']}")
    lines.append(f"duration:    {info['duration_s']:.3f} s  ({_when(info['start_ns'])} -> {_when(info['end_ns'])})")
    lines.append(f"messages:    {info['messages']}")
    rec = info["recording"]
    if rec:
        lines.append(f"recorded by: palpa {rec.get('palpa_version', '?')} on {rec.get('host', '?')} "
                     f"(node {rec.get('recorder', '?')}, mcap {rec.get('mcap_library', '?')})")
    lines.append(f"topics ({len(info['topics'])}):")
    width = max((len(_shown(t)) for t in info["topics"]), default=5)
    total_gaps = restarts = 0
    for topic, t in info["topics"].items():
        d = t["drops"]
        total_gaps += d["gaps"]
        restarts += d["restarts"]
        extra = [f"{d['gaps']} dropped"] if d["gaps"] else []
        if d["restarts"]:
            extra.append(f"{d['restarts']} publisher restarts")
        if d["decode_errors"]:
            extra.append(f"{d['decode_errors']} malformed")
        if t["latched"]:
            extra.append("latched")
        if not t["schema"]:
            extra.append(t.get("schema_note", "no schema"))
        lines.append(f"  {_shown(topic):<{width}}  {_shown('/'.join(t['types'])) or '?':<22} {t['messages']:>9} msgs "
                     f"{t['rate_hz']:>9.2f} Hz  from {_shown(', '.join(t['publishers'])) or '?'}"
                     + (f"  [{'; '.join(extra)}]" if extra else ""))
    drops = [f"{total_gaps} messages missing by sequence number"] if total_gaps else []
    if restarts:  # a restarted publisher lost what it held, and what it was sent while down
        drops.append(f"{restarts} publisher restart(s): data may be lost")
    lines.append(f"drops:       {'; '.join(drops)}" if drops else "drops:       none (no sequence gaps, no restarts)")
    if info["services"]:
        lines.append(f"services ({len(info['services'])}):")
        for name, sv in info["services"].items():
            lines.append(f"  {name}  [{sv['request']} -> {sv['response']}]  {sv['requests']} requests, "
                         f"{sv['replies']} replies ({sv['faults']} failed) to {sv['callers']} caller(s)")
    if info["nodes"]:
        lines.append(f"nodes ({len(info['nodes'])}):")
        for name, n in info["nodes"].items():
            pubs = _shown(", ".join(sorted(n.get("publishes", {}))))
            lines.append(f"  {_shown(name)} (pid {n.get('pid', '?')} on {_shown(n.get('host', '?'))}) "
                         f"publishes: {pubs or '-'}")
    for a in info["attachments"]:
        lines.append(f"attachment:  {a['name']} ({a['media_type']}, {a['bytes']} bytes)")
    return "\n".join(lines)
