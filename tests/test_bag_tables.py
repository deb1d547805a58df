"""Recordings as data (issue 42): a recorded scan exported to Parquet and CSV reads back with pandas and pyarrow,
row for row what ``bag info`` counts and value for value what the MCAP holds; aligned tables state and keep their
method and tolerance; ``palpa.bag.read`` is the same tables in Python."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import msgpack
import pandas as pd
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

import palpa.bag
from palpa.cli.main import main
from palpa.launch import load_launch, parse_overrides
from palpa.launch.compose import compose_plan
from palpa.record.format import BagError
from palpa.record.info import bag_info
from palpa.record.tables import Flattener
from palpa.record.testing import Rec, write_bag
from palpa.timing.clock import MockClock
from palpa.timing.compose import Composition
from tests.test_launch_smoke import REPO

# a few lines over the r 5 mm tumour, measured geometry given as a user would (no prepare step in memory)
SMALL = ["region_mm:=[38.0, 12.0, 50.0, 24.0]", "spacing_mm:=4.0", "speed_mm_s:=40.0", "touch_grid:=2",
         f"geometry:={REPO / 'phantoms' / 'measured' / 'airfloat_tumours.yaml'}"]


def record_scan(run_dir: Path) -> Path:
    """launch/scan_sim.yaml's nodes and recorder composed in memory on a mock clock; returns the recording."""
    from palpa.targets import load_node_class

    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "launch.resolved.yaml").write_text("# the scan\nnodes: []\n")
    plan = compose_plan(load_launch(REPO / "launch" / "scan_sim.yaml", parse_overrides(SMALL), run_dir=run_dir))
    comp = Composition(clock=MockClock(1_700_000_000_000_000_000), heartbeat_s=0)
    for n in json.loads(plan.nodes[0].cmd[-1])["nodes"]:  # type: ignore[index]
        comp.add(load_node_class(n["target"]), n["name"], n["params"], required=n["required"])
    assert comp.run(max_sim_s=120.0) == 0
    return run_dir / "recording.mcap"


@pytest.fixture(scope="module")
def scan_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_scan(tmp_path_factory.mktemp("scan"))


def _official(bag: Path) -> dict[str, list[tuple[int, int, dict[str, Any]]]]:
    """topic -> [(log_time, sequence, decoded payload)] as the official reader and plain msgpack see them."""
    out: dict[str, list[tuple[int, int, dict[str, Any]]]] = {}
    with open(bag, "rb") as fh:
        for _s, ch, msg in make_reader(fh).iter_messages(log_time_order=False):
            if not ch.topic.startswith("_palpa/"):
                out.setdefault(ch.topic, []).append((msg.log_time, msg.sequence, msgpack.unpackb(msg.data)))
    return out


def _cell(payload: Any, column: str) -> Any:
    for part in column.split("."):
        payload = payload[int(part)] if isinstance(payload, list) else payload[part]
    return payload


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN, also inside lists and maps."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return type(a) is type(b) and bool(a == b) or (isinstance(a, int | float) and isinstance(b, int | float)
                                                     and not isinstance(a, bool) and a == b)


def _check_table(df: pd.DataFrame, recorded: list[tuple[int, int, dict[str, Any]]], *, csv: bool) -> None:
    assert len(df) == len(recorded)
    assert list(df["_log_time_ns"]) == [r[0] for r in recorded]
    assert list(df["_sequence"]) == [r[1] for r in recorded]
    for column in df.columns:
        if column.startswith("_"):
            continue
        for got, (_t, _s, payload) in zip(df[column].tolist(), recorded, strict=True):
            want = _cell(payload, column)
            if csv and isinstance(want, list | dict):
                got = json.loads(got)
            elif csv and want == "":
                got = "" if isinstance(got, float) and math.isnan(got) else got  # pandas reads "" back as NaN
            if hasattr(got, "tolist"):
                got = got.tolist()
            assert _same(got, want), (column, got, want)


def test_a_recorded_scan_exported_to_parquet_and_csv_reads_back_equal(scan_bag: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    info = bag_info([scan_bag])["topics"]
    recorded = _official(scan_bag)
    assert {"probe/heights", "stiffness/sample", "robot/plan", "pressure/state"} <= set(recorded)
    assert main(["bag", "export", str(scan_bag), "--format", "parquet", "-o", str(tmp_path / "pq")]) == 0
    assert "rows of 11 topics" in capsys.readouterr().out
    assert main(["bag", "export", str(scan_bag), "--format", "csv", "-o", str(tmp_path / "csv")]) == 0
    for topic, msgs in recorded.items():
        name = topic.replace("/", ".")
        table = pq.read_table(tmp_path / "pq" / f"{name}.parquet")
        assert table.schema.metadata[b"palpa.topic"] == topic.encode()
        assert table.num_rows == info[topic]["messages"] == len(msgs)
        _check_table(table.to_pandas(), msgs, csv=False)
        frame = pd.read_csv(tmp_path / "csv" / f"{name}.csv")
        assert len(frame) == info[topic]["messages"]
        _check_table(frame, msgs, csv=True)
    heights = pd.read_csv(tmp_path / "csv" / "probe.heights.csv")
    assert [c for c in heights.columns if c.startswith("h_mm")] == ["h_mm.0", "h_mm.1", "h_mm.2", "h_mm.3"]


def test_palpa_bag_read_is_the_same_tables_and_plots_force_against_depth(scan_bag: Path) -> None:
    frames = palpa.bag.read(scan_bag, topics=["stiffness/sample", "pressure/.*"])
    assert sorted(frames) == ["pressure/state", "pressure/status", "stiffness/sample"]
    recorded = _official(scan_bag)
    _check_table(frames["stiffness/sample"], recorded["stiffness/sample"], csv=False)
    samples = frames["stiffness/sample"]
    pressed = samples[samples["valid"]]
    assert len(pressed) > 100 and (pressed["force_n"] > 0).all() and (pressed["d_in_mm"] > 0).all()
    # the docs' example, run as written on this recording (docs/recording.md)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    doc = (REPO / "docs" / "recording.md").read_text()
    code = next(block.partition("\n")[2] for block in doc.split("```python")[1:] if "palpa.bag.read" in block)
    code = code.partition("```")[0].replace('"runs/latest/recording.mcap"', repr(str(scan_bag)))
    scope: dict[str, Any] = {}
    exec(code, scope)  # noqa: S102 - our own documentation's example
    assert len(scope["ax"].collections[0].get_offsets()) == len(pressed)
    assert scope["ax"].get_xlabel().startswith("indentation depth")
    plt.close("all")


def _two_topics(path: Path) -> Path:
    """'a' at 0, 10, 20, 30 ms (value = t in ms); 'b' at 4, 16, 60 ms (value = 100 + t)."""
    ms = 1_000_000

    def text(value: float) -> bytes:
        return msgpack.packb({"x": value, "stamp_ns": 1, "tag": f"v{value:g}"})

    msgs = [Rec("a", t * ms, text(float(t)), i + 1, publish_time=t * ms) for i, t in enumerate((0, 10, 20, 30))]
    msgs += [Rec("b", t * ms, text(100.0 + t), i + 1, publish_time=t * ms) for i, t in enumerate((4, 16, 60))]
    return write_bag(path, sorted(msgs, key=lambda m: m.log_time))


def test_aligned_tables_nearest_and_linear_within_the_tolerance(tmp_path: Path) -> None:
    frames = palpa.bag.read(_two_topics(tmp_path / "ab.mcap"))
    near = palpa.bag.align(frames, palpa.bag.AlignSpec(topic="a", tolerance_s=0.005))
    assert list(near["time_s"]) == [0.0, 0.01, 0.02, 0.03]
    assert list(near["a.x"]) == [0.0, 10.0, 20.0, 30.0]
    # b's nearest: 4 ms (4 ms away), 16 (6 away: beyond 5 ms), 16 (4 away), 16 (14 away)
    assert near["b.x"].tolist()[0] == 104.0 and near["b.x"].tolist()[2] == 116.0
    assert pd.isna(near["b.x"]).tolist() == [False, True, False, True]
    assert near["b.tag"].tolist()[:1] == ["v104"] and pd.isna(near["b.tag"].tolist()[1])
    linear = palpa.bag.align(frames, palpa.bag.AlignSpec(topic="a", method="linear", tolerance_s=0.006))
    # between 4 -> 104 and 16 -> 116: t = 10 ms gives 110; t = 0 lies before b's first sample
    assert pd.isna(linear["b.x"][0]) and linear["b.x"][1] == pytest.approx(110.0)
    assert linear["b.x"][2] == pytest.approx(120.0) and pd.isna(linear["b.x"][3])
    assert linear["b._sequence"].tolist()[1:3] == [1, 2]  # integers are never interpolated: the nearest sample's
    grid = palpa.bag.align(frames, palpa.bag.AlignSpec(rate_hz=50.0, tolerance_s=0.005))
    assert grid["time_ns"].tolist() == [0, 20_000_000, 40_000_000, 60_000_000]
    assert grid["a.x"].tolist()[:2] == [0.0, 20.0] and grid["b.x"].tolist()[3] == 160.0


def test_aligned_export_states_its_method_and_refuses_what_it_cannot_do(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    bag = _two_topics(tmp_path / "ab.mcap")
    out = tmp_path / "aligned.parquet"
    assert main(["bag", "export", str(bag), "--format", "parquet", "--align", "a", "--method", "linear",
                 "--tolerance", "0.006", "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "rows at each a message; other topics by linear interpolation within 0.006 s" in said
    table = pq.read_table(out)
    assert table.schema.metadata[b"palpa.align"].decode() in said
    assert table.column("b.x").to_pylist()[1] == pytest.approx(110.0)
    assert main(["bag", "export", str(bag), "--format", "csv", "--align", "nothere", "-o",
                 str(tmp_path / "x.csv")]) == 1
    assert "--align nothere: the recording has no message on it" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "x.csv.partial").exists()
    assert main(["bag", "export", str(bag), "--format", "csv", "-o", str(out)]) == 1
    assert "already exists" in capsys.readouterr().err
    assert main(["bag", "export", str(bag), "--format", "csv"]) == 1
    assert "--format needs -o" in capsys.readouterr().err
    with pytest.raises(BagError, match="not msgpack"):
        palpa.bag.read(write_bag(tmp_path / "bad.mcap", [Rec("a", 1, b"\xc1", 1)]))
    deep = b"\x91" * 100_000 + b"\x00"  # an array in an array ... 10^5 deep: the recorder keeps what the wire carried
    with pytest.raises(BagError, match="nested deeper"):  # a clear refusal, not a RecursionError's traceback
        palpa.bag.read(write_bag(tmp_path / "deep.mcap", [Rec("a", 1, deep, 1)]))


def test_flattening_nested_maps_fixed_arrays_and_units_from_the_schema() -> None:
    schema = {"$defs": {"P": {"type": "object", "properties": {
        "x": {"type": "number"}, "force": {"type": "number", "x-unit": "N"},
        "depth_mm": {"type": "number", "x-unit": "mm"}}}},
        "type": "object", "properties": {
            "pose": {"$ref": "#/$defs/P"},
            "q": {"type": "array", "prefixItems": [{"type": "number"}, {"type": "number"}], "items": False},
            "hist": {"type": "array", "items": {"type": "number"}}}}
    flat = Flattener(json.dumps(schema).encode())
    row = flat.flatten({"pose": {"x": 1.0, "force": 2.0, "depth_mm": 3.0}, "q": [4.0, 5.0], "hist": [6.0, 7.0]})
    assert row == {"pose.x": 1.0, "pose.force[N]": 2.0, "pose.depth_mm": 3.0, "q.0": 4.0, "q.1": 5.0,
                   "hist": [6.0, 7.0]}
    # no schema: maps still flatten, lists stay whole; a wrong-length array is not split
    assert Flattener(None).flatten({"a": {"b": 1}, "q": [1, 2]}) == {"a.b": 1, "q": [1, 2]}
    assert flat.flatten({"q": [1.0]}) == {"q": [1.0]}
