"""Fibre DAQ: calibration, clock filter, and the serial driver against the pty emulator (the codec: test_devices_fibre_daq.py)."""

from __future__ import annotations

import contextlib
import math
import random
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from devices.fibre_daq import CHANNELS
from emulators.fibre_daq import FibreDaqEmulator, fixed_pose, source_from_heights
from models.clock_offset import ClockOffsetEstimator
from models.fibre_calibration import FibreCalibration, FibreCalibrationError, load_calibration
from nodes.drivers.fibre import (
    FibreCommandError,
    FibreCounters,
    FibreDriver,
    FibreNotConnectedError,
    FibreSample,
)
from nodes.drivers.fibre_serial import SerialFibreDriver
from tests.procs import ProcessGroup, wait_until

pytestmark = pytest.mark.timeout(30)

DATA = Path(__file__).parent / "data"
CAL_FILE = DATA / "fibre_calibration.yaml"
REPO = Path(__file__).resolve().parents[1]



def collect(drv: SerialFibreDriver, n: int, timeout_s: float = 5.0) -> list[FibreSample]:
    """Read until at least ``n`` samples arrived."""
    out: list[FibreSample] = []
    try:
        wait_until(lambda: len(out) >= n, timeout_s, f"{n} samples", step=lambda: out.extend(drv.read(0.1)))
    except AssertionError as exc:
        pytest.fail(f"{exc}: got {len(out)}; status {drv.status()}")
    return out


def counters(drv: SerialFibreDriver) -> FibreCounters:
    return drv.status().counters


@pytest.fixture
def cal() -> FibreCalibration:
    return load_calibration(CAL_FILE)


@pytest.fixture
def make_emu(stack: contextlib.ExitStack) -> Callable[..., FibreDaqEmulator]:
    return lambda **kw: stack.enter_context(FibreDaqEmulator(**kw))  # type: ignore[arg-type]


@pytest.fixture
def make_driver(cal: FibreCalibration, stack: contextlib.ExitStack) -> Callable[..., SerialFibreDriver]:
    def make(port: str, **kw: object) -> SerialFibreDriver:
        kw.setdefault("backoff_s", (0.01, 0.1))
        return stack.enter_context(SerialFibreDriver(port, 115200, cal, **kw))  # type: ignore[arg-type]

    return make


def settled(drv: SerialFibreDriver) -> FibreCounters:
    """Drain what is queued, then return a counter baseline taken while data flows."""
    collect(drv, 5)
    return counters(drv)


# --- calibration ----------------------------------------------------------------------


def test_example_calibration_maps_raw_to_mm(cal: FibreCalibration) -> None:
    assert [ch.name for ch in cal.channels] == list(CHANNELS)
    raw = (21000.0, 21500.0, 20500.0, 33000.0)
    for ch, r, h in zip(cal.channels, raw, cal.heights_mm(raw), strict=True):
        assert h == pytest.approx(sum(c * r**k for k, c in enumerate(ch.poly)), abs=1e-12)
        assert 0.0 < h < 4.0
        assert ch.raw_for_height(h) == pytest.approx(r, abs=1e-6)
    with pytest.raises(ValueError, match="outside the calibrated span"):
        cal.channels[0].raw_for_height(50.0)


def _write_cal(tmp_path: Path, channels_yaml: str, extra: str = "") -> Path:
    p = tmp_path / "cal.yaml"
    p.write_text(f"{extra}channels:\n{channels_yaml}")
    return p


_GOOD = "  - {{name: {n}, raw_range: [0, 1000], poly: [0.0, 0.001]}}\n"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("".join(_GOOD.format(n=n) for n in CHANNELS[:3]), "expected 4 channels"),
        ("".join(_GOOD.format(n=n) for n in ("SPS2", "SPS1", "SPS3", "S1")), "name 'SPS2', expected 'SPS1'"),
        (_GOOD.format(n="SPS1").replace("0.001", "lots") + "".join(_GOOD.format(n=n) for n in CHANNELS[1:]),
         r"cal.yaml:2:\d+: channels\[0\].poly\[1\]: expected `float`, got `str`"),
        (_GOOD.format(n="SPS1").replace("[0.0, 0.001]", "[0.0, 0.001, -0.000002]") + "".join(_GOOD.format(n=n) for n in CHANNELS[1:]), "not monotonic"),
        (_GOOD.format(n="SPS1").replace("[0, 1000]", "[1000, 0]") + "".join(_GOOD.format(n=n) for n in CHANNELS[1:]), "raw_range"),
        (_GOOD.format(n="SPS1").replace("}", ", gain: 2}") + "".join(_GOOD.format(n=n) for n in CHANNELS[1:]), r"cal.yaml:2:\d+: unknown key 'gain' in channels\[0\]"),
    ],
)
def test_load_calibration_errors_name_file_and_channel(tmp_path: Path, text: str, match: str) -> None:
    path = _write_cal(tmp_path, text)
    with pytest.raises(FibreCalibrationError, match=match) as exc:
        load_calibration(path)
    assert str(path) in str(exc.value)


def test_calibration_reads_yaml_1_2_numbers(tmp_path: Path) -> None:
    """1e-3 is a float (YAML 1.2 core schema; PyYAML's 1.1 rules read it as a string)."""
    text = _GOOD.format(n="SPS1").replace("0.001", "1e-3") + "".join(_GOOD.format(n=n) for n in CHANNELS[1:])
    assert load_calibration(_write_cal(tmp_path, text)).channels[0].poly == (0.0, 1e-3)


def test_load_calibration_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FibreCalibrationError, match="cannot read"):
        load_calibration(tmp_path / "nope.yaml")


# --- clock filter (synthetic, deterministic) ----------------------------------------


def test_clock_estimator_tracks_offset_and_drift_through_latency_spikes() -> None:
    rng = random.Random(1)
    est = ClockOffsetEstimator(window_s=10.0, block_s=0.25)
    offset0, drift = 1_700_000_000_000_000_000, 150e-6  # device clock slow by 150 ppm

    def true_offset(dev: int) -> float:
        return offset0 + drift * dev

    assert est.offset_ns() is None
    for k in range(6000):  # 12 s at 500 Hz
        dev = k * 2_000_000
        latency = 100_000 + rng.expovariate(1 / 1_000_000)  # >= 0.1 ms, mean 1 ms
        if rng.random() < 0.05:
            latency += 50_000_000  # scheduler hiccup
        if 2500 <= k < 2750:
            latency += 30_000_000  # half a second in which the host was busy
        est.update(dev, round(dev + true_offset(dev) + latency))
    dev = 5999 * 2_000_000
    host = est.to_host_ns(dev)
    assert host is not None
    err = host - (dev + true_offset(dev))
    assert 0 <= err < 300_000  # within 0.3 ms, biased by the minimum latency only
    assert est.drift_ppm == pytest.approx(150.0, abs=15.0)
    est.reset()
    assert est.offset_ns() is None


# --- driver against the emulator -------------------------------------------------------


@pytest.mark.system
def test_streams_calibrated_heights(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver], cal: FibreCalibration) -> None:
    heights = (1.0, 1.2, 0.9, 2.5)
    emu = make_emu(source=source_from_heights(cal, lambda _t: heights))
    drv = make_driver(emu.port)
    assert isinstance(drv, FibreDriver)
    samples = collect(drv, 50)
    for s in samples:
        for got, want in zip(s.heights_mm, heights, strict=True):
            assert got == pytest.approx(want, abs=1e-4)  # raw counts are integers on the wire
    seqs = [s.seq for s in samples]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    c = counters(drv)
    assert (c.resyncs, c.corrupt, c.dropped, c.reconnects) == (0, 0, 0, 0)
    assert drv.status().connected


@pytest.mark.system
def test_garbage_bytes_resync_without_losing_lines(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    base = settled(drv)
    emu.inject_garbage(b"\x00\xff#noise\xfe")  # glued to the front of the next line
    wait_until(lambda: counters(drv).resyncs >= base.resyncs + 1, what="first resync")
    emu.inject_garbage(b"\x00junk line\r\n")  # a line of its own
    wait_until(lambda: counters(drv).resyncs >= base.resyncs + 2, what="second resync")
    collect(drv, 10)
    c = counters(drv)
    assert (c.resyncs - base.resyncs, c.corrupt - base.corrupt, c.dropped - base.dropped) == (2, 0, 0)


@pytest.mark.system
def test_dropped_lines_are_counted_as_sequence_gap(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    got = collect(drv, 5)
    base = counters(drv)
    emu.drop_next(3)
    wait_until(lambda: counters(drv).dropped >= base.dropped + 3, what="gap of 3")
    got += collect(drv, 10)
    seqs = [s.seq for s in got]
    assert sum(b - a - 1 for a, b in zip(seqs, seqs[1:], strict=False)) == 3
    c = counters(drv)
    assert (c.dropped - base.dropped, c.corrupt - base.corrupt, c.resyncs - base.resyncs) == (3, 0, 0)


@pytest.mark.system
def test_corrupt_checksum_is_rejected_and_counted(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    base = settled(drv)
    emu.corrupt_next(2)
    wait_until(lambda: counters(drv).corrupt >= base.corrupt + 2, what="two corrupt lines")
    collect(drv, 10)
    c = counters(drv)
    assert (c.corrupt - base.corrupt, c.dropped - base.dropped, c.resyncs - base.resyncs) == (2, 2, 0)
    assert "checksum" in (drv.status().last_error or "")


@pytest.mark.system
def test_partial_line_resyncs_on_next_start_marker(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    base = settled(drv)
    emu.truncate_next(1)
    wait_until(lambda: counters(drv).resyncs >= base.resyncs + 1, what="resync after partial line")
    collect(drv, 10)
    c = counters(drv)
    assert (c.resyncs - base.resyncs, c.dropped - base.dropped, c.corrupt - base.corrupt) == (1, 1, 0)


@pytest.mark.system
def test_unplug_replug_recovers_same_driver(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port)
    drv.set_rate(250)
    collect(drv, 5)
    emu.unplug()
    wait_until(lambda: not drv.status().connected, what="driver to notice the unplug")
    assert emu.port in (drv.status().last_error or "")
    drv.read(0)  # whatever arrived before the unplug
    assert drv.read(0.05) == []
    with pytest.raises(FibreNotConnectedError):
        drv.zero()
    emu.replug(reboot=True)  # device restarts at its boot rate (500 Hz)...
    wait_until(lambda: drv.status().connected, what="reconnect")
    wait_until(lambda: emu.rate_hz == 250, what="driver to re-apply its rate")  # ...and gets 250 Hz back
    after = collect(drv, 10)
    st = drv.status()
    assert st.counters.reconnects == 1
    assert st.rate_hz == 250
    assert st.counters.dropped == 0  # the reboot restarted seq: not a gap
    assert after[-1].seq < 1000


@pytest.mark.system
def test_driver_waits_for_device_that_appears_later(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver], cal: FibreCalibration) -> None:
    emu = make_emu()
    emu.unplug()
    with pytest.raises(FibreNotConnectedError, match=emu.port):
        SerialFibreDriver(emu.port, 115200, cal).open()
    drv = make_driver(emu.port, require_device=False)
    assert not drv.status().connected
    assert drv.read(0.02) == []
    emu.replug()
    collect(drv, 5)
    assert drv.status().connected


@pytest.mark.system
def test_command_channel(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver], cal: FibreCalibration) -> None:
    emu = make_emu(source=fixed_pose((20000.0, 21000.0, 22000.0, 30000.0)))
    drv = make_driver(emu.port)
    assert drv.identify().startswith("palpa-fibre-daq,")
    drv.set_rate(100)
    assert emu.rate_hz == 100 and drv.status().rate_hz == 100
    drv.read(0)
    tail = collect(drv, 5)[-3:]
    assert [b.device_stamp_ns - a.device_stamp_ns for a, b in zip(tail, tail[1:], strict=False)] == [10_000_000, 10_000_000]
    with pytest.raises(FibreCommandError, match="range"):
        drv.set_rate(1e6)
    with pytest.raises(ValueError):
        drv.set_rate(-1)
    # zero: the current pose reads zero_mm (0.0 in the example file) from now on
    drv.zero()
    drv.read(0)
    for s in collect(drv, 3):
        assert s.heights_mm == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=1e-9)
    drv.close()
    wait_until(lambda: not emu.streaming, what="$STOP on close")
    assert emu.commands[0] == "START" and emu.commands[-1] == "STOP"


@pytest.mark.system
def test_clock_offset_converges_across_32bit_wrap(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu(clock_start_us=(1 << 32) - 300_000, drift_ppm=400.0)  # wraps after 0.3 s
    drv = make_driver(emu.port)
    samples: list[FibreSample] = []
    handed_ns: list[int] = []   # when each sample reached this test: after it arrived at the driver

    def take() -> None:
        got = drv.read(0.1)
        samples.extend(got)
        handed_ns.extend([time.time_ns()] * len(got))

    wait_until(lambda: len(samples) >= 1200, 10.0, "1200 samples", step=take)  # ~2.4 s
    dev = [s.device_stamp_ns for s in samples]
    steps = [b - a for a, b in zip(dev, dev[1:], strict=False)]
    assert min(steps) > 0 and dev[-1] > (1 << 32) * 1000  # unwrapped, monotonic
    true_ns = dict(emu.sample_wall_ns)
    # How near the sampling instant a stamp can be is set by how fast samples crossed the pty: a minimum-delay
    # filter stamps each sample about its block's fastest delay late. Idle that is well under a millisecond; with
    # both cores busy the emulator's thread and this one run tens of ms late for whole blocks, and no estimator
    # could know. So the bound is what the run's blocks allowed (the median over its 0.25 s blocks of each one's
    # fastest sample, from sampling to reaching this test: an upper bound of its delay), plus 2 ms.
    blocks: dict[int, int] = {}
    for s, h in zip(samples, handed_ns, strict=True):
        k = s.device_stamp_ns // 250_000_000
        blocks[k] = min(h - true_ns[s.seq], blocks.get(k, h - true_ns[s.seq]))
    allowed = sorted(blocks.values())[len(blocks) // 2] + 2_000_000
    errs = sorted(s.stamp_ns - true_ns[s.seq] for s in samples[-250:])
    assert -2_000_000 < errs[len(errs) // 2] < allowed, (errs[len(errs) // 2], sorted(blocks.values()))
    # the device runs 400 ppm fast; over the run's span, the blocks' delays varying by `spread` can tilt the fitted
    # line by up to spread / span (idle: ~100 ppm; loaded: thousands)
    spread_ns = max(blocks.values()) - min(blocks.values())
    slack_ppm = 1e6 * spread_ns / (dev[-1] - dev[0]) + 150.0
    st = drv.status()
    assert st.clock_offset_ns is not None and st.clock_drift_ppm is not None
    assert abs(st.clock_drift_ppm + 400.0) < slack_ppm, (st.clock_drift_ppm, slack_ppm)


@pytest.mark.system
def test_overrun_when_caller_does_not_read(make_emu: Callable[..., FibreDaqEmulator], make_driver: Callable[..., SerialFibreDriver]) -> None:
    emu = make_emu()
    drv = make_driver(emu.port, max_queue=10)
    wait_until(lambda: counters(drv).samples >= 40, what="40 samples")
    out = drv.read(0)
    assert len(out) == 10
    c = counters(drv)
    assert c.overruns >= 30 and c.overruns + 10 >= c.samples - 5


# --- command-line emulator ----------------------------------------------------------


@pytest.mark.system
def test_cli_prints_port_and_stops_on_ctrl_c(make_driver: Callable[..., SerialFibreDriver],
                                             procs: ProcessGroup) -> None:
    # started with SIGINT ignored, as a shell starts a background job: the emulator must still stop on Ctrl-C
    proc = procs.start([sys.executable, "-m", "emulators.fibre_daq", "--rate", "200"], cwd=str(REPO),
                       ignore_sigint=True)
    port = proc.first_line(15.0)
    drv = make_driver(port)
    assert all(math.isfinite(h) for h in collect(drv, 5)[0].heights_mm)
    proc.signal(signal.SIGINT)
    assert proc.wait(10.0) == 0
    assert not Path(port).exists()
