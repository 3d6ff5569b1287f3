"""The fast paths agree: one realistic capture through all of them.

The vectorised capture decoder (``hdrd replay``), the push parser (what the live source runs)
and the live daemon's path (a real pty read by :class:`hdrd.io.wire.sources.SerialSource`, each frame
through :meth:`hdrd.daemon.pipeline.Pipeline.feed`) must give the same frames, the same counters and
the same messages as the replay path (:func:`hdrd.io.wire.capture.decode_capture` then
:meth:`~hdrd.daemon.pipeline.Pipeline.feed_array`) on the same bytes. test_parser, test_pipeline and
test_replay check each pair on small or synthetic inputs; this module ties all of them together
on one 10-minute 100 Hz drive with garbage, CRC errors, dropped frames and a device-clock wrap.

It also covers the other shortcuts taken for speed: the daemon's batched reading
(:meth:`Pipeline.until_step_s`: how long the port may go unread without delaying a step; the
pauses it makes are tested in test_pacing.py), the JSON formatter's fast path, and the lazy
imports that keep ``hdrd replay`` light. The direct read path of a local serial port:
test_serialport.py.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.calibrate import given_bias
from hdrd.core.hdr import HdrParams
from hdrd.core.methods import MethodSetup
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.net.formats import _format_clean, format_json
from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import Frame, array_to_frames
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.sources import DeviceBack, DeviceLost, EndOfInput, SerialSource
from hdrd.sim import simulate_drive
from hdrd.sim.fakegyro import FakeGyro
from hdrd.sim.profiles import profile_frames

FAULTS: dict[str, Any] = {"garbage": 0.01, "crc_errors": 0.005, "drop": 0.002, "seed": 5}


@pytest.fixture(scope="module")
def drive_frames() -> np.ndarray:
    """A 10-minute "mixed" drive (plus 30 s at standstill) at 100 Hz, its device clock
    starting 200 s before the 2**32 us wrap."""
    log = simulate_drive("mixed", 10.0, 3, hz=100.0)
    return profile_frames(log, t0_us=2**32 - 200_000_000, seq0=65_000)


@pytest.fixture(scope="module")
def capture(
    drive_frames: np.ndarray, tmp_path_factory: pytest.TempPathFactory
) -> tuple[bytes, FakeGyro]:
    path = tmp_path_factory.mktemp("fastpaths") / "drive.bin"
    g = FakeGyro(drive_frames, **FAULTS)
    g.write_capture(path)
    return Path(path).read_bytes(), g


def replay_messages(data: bytes, config: PipelineConfig) -> list[dict[str, Any]]:
    """What ``hdrd replay`` publishes (hdrd.daemon.replay.replay_capture, with a PipelineConfig)."""
    arr, st_ = decode_capture(data)
    p = Pipeline(config)
    msgs = p.feed_array(arr, st_.bad_before)
    msgs.extend(p.finish(int(st_.bad_frames)))
    return msgs


CONFIGS = {
    "bias given": PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))),
    "start-up calibration": PipelineConfig(startup_s=1.0),
}


def test_decoder_and_push_parser_agree_with_what_was_sent(capture: tuple[bytes, FakeGyro]) -> None:
    data, g = capture
    arr, cst = decode_capture(data)
    p = Parser()
    frames: list[Frame] = []
    bad_before: list[int] = []
    for i in range(0, len(data), 64):
        frames += p.feed(data[i : i + 64])
        bad_before += p.bad_before
    frames += p.flush()
    bad_before += p.bad_before
    assert array_to_frames(arr) == frames
    assert cst == p.stats  # every counter
    assert cst.bad_before.tolist() == bad_before
    # ... and both are what the fake gyro put on the wire.
    assert frames == g.sent_frames()
    inj = g.injected
    assert cst.frames == inj.frames > 60_000
    assert cst.bad_frames == inj.expected_bad_frames > 100
    assert cst.lost_frames == inj.missing_frames > 0
    assert cst.clock_wraps == 1 and cst.seq_clock_mismatch == 0 and cst.seq_resets == 0
    assert cst.garbage_bytes == inj.garbage_bytes + 16 * inj.crc_errors


@pytest.mark.slow
def test_live_daemon_path_equals_replay_on_the_same_bytes(
    capture: tuple[bytes, FakeGyro], drive_frames: np.ndarray, fake_gyro: Any
) -> None:
    """A real pty read by SerialSource, each frame into Pipeline.feed with the source's bad-frame
    count (as hdrd run does) == decode_capture + feed_array (as hdrd replay does)."""
    data, written = capture
    live = {name: Pipeline(cfg) for name, cfg in CONFIGS.items()}
    live_msgs: dict[str, list[dict[str, Any]]] = {name: [] for name in CONFIGS}
    got: list[Frame] = []
    g = fake_gyro(drive_frames, speedup=0, **FAULTS)  # the same stream, faults and all, on a pty
    with SerialSource(g.path) as src:
        assert src.reader._fd_poll is not None  # the direct read path is the one under test
        g.start()
        while True:
            item = src.recv(0.5)
            if item is None:
                if g.done:
                    break
                continue
            assert not isinstance(item, (DeviceLost, DeviceBack, EndOfInput)), item
            assert src.bad_frames == src.stats.bad_frames
            got.append(item)
            for name, p in live.items():
                live_msgs[name].extend(p.feed(item, src.bad_frames))
        assert g.error is None and src.link.lost == 0
        for name, p in live.items():
            live_msgs[name].extend(p.finish(src.bad_frames))
        assert src.stats == decode_capture(data)[1]
    assert got == written.sent_frames()
    for name, cfg in CONFIGS.items():
        replayed = replay_messages(data, cfg)
        assert len(replayed) > 600
        assert live_msgs[name] == replayed, name
    steps = [m["step"] for m in replayed]
    assert steps == list(range(len(steps)))  # a step per second of device time, across the wrap
    assert replayed[-1]["bad_frames"] == written.injected.expected_bad_frames


# --------------------------------------------------------------------------- batched reads


def fed(frames_us: list[int], T: float = 1.0) -> Pipeline:
    p = Pipeline(PipelineConfig(setup=MethodSetup(hdr=HdrParams(T=T), bias=given_bias(0.0))))
    for i, t in enumerate(frames_us):
        p.feed(Frame(i & 0xFFFF, t % 2**32, 32768, 0, None))
    return p


def test_until_step_s_on_a_regular_stream() -> None:
    assert fed([]).until_step_s() is None
    assert fed([0]).until_step_s() is None  # one sample: no interval known yet
    # 1 kHz from t = 0: after sample k (k >= 1) the block ends at 1 s, the interval is 1 ms.
    for k in (1, 10, 500, 998):
        assert fed([1000 * i for i in range(k + 1)]).until_step_s() == pytest.approx(
            (1e6 - 1000 * k - 1000) / 1e6
        )
    # The first sample of block 1 closes block 0; the new block has one sample: unknown again.
    assert fed([1000 * i for i in range(1001)]).until_step_s() is None
    # The interval is measured from the block's start edge, so it errs long (the answer early).
    p = fed([0, 1_000_300, 1_001_300, 1_002_300])  # block 1 starts at 1 s, first sample 300 us in
    assert p.until_step_s() == pytest.approx((2e6 - 1_002_300 - 2_300 / 2) / 1e6)
    p.finish()
    assert p.until_step_s() is None
    p = fed([0, 1000, 2000])
    p.resync()
    assert p.until_step_s() is None


@settings(max_examples=60)
@given(
    hz=st.sampled_from([10.0, 100.0, 300.0, 1000.0, 2500.0]),
    n=st.integers(2, 3000),
    jitter=st.floats(0.0, 0.45),
    seed=st.integers(0, 2**31),
)
def test_until_step_s_never_sleeps_past_the_closing_sample(
    hz: float, n: int, jitter: float, seed: int
) -> None:
    """If the daemon pauses until_step_s() after a sample, the sample that closes the open
    block still lies ahead (device time), so the pause never delays a step."""
    rng = np.random.default_rng(seed)
    period = 1e6 / hz
    t = np.rint(np.arange(n) * period + rng.uniform(-jitter, jitter, n) * period).astype(np.int64)
    t = np.maximum.accumulate(t - t[0]) + np.arange(n)  # strictly increasing from 0
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(0.0))))
    block = t // 1_000_000
    for i, tu in enumerate(t.tolist()):
        p.feed(Frame(i & 0xFFFF, tu, 32768, 0, None))
        s = p.until_step_s()
        if s is None:
            continue
        closing = np.flatnonzero(block > block[i])
        if closing.size:
            assert tu + s * 1e6 <= t[closing[0]]
        assert s < 1.0


# --------------------------------------------------------------------------- JSON, imports

_json_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.builds(np.float64, st.floats(allow_nan=True)),
    st.builds(np.int32, st.integers(-(2**31), 2**31 - 1)),
    st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=3),
    st.dictionaries(st.text(max_size=3), st.one_of(st.none(), st.integers()), max_size=2),
)


@given(st.dictionaries(st.one_of(st.text(max_size=6), st.integers(0, 3)), _json_values, max_size=8))
def test_json_fast_path_writes_what_the_cleaning_path_writes(msg: dict[Any, Any]) -> None:
    assert format_json(msg) == _format_clean(msg)


def test_json_fast_path_on_pipeline_messages(capture: tuple[bytes, FakeGyro]) -> None:
    msgs = replay_messages(capture[0], CONFIGS["bias given"])
    assert all(
        isinstance(v, (str, int, float)) and not (isinstance(v, float) and math.isnan(v))
        for m in msgs
        for v in m.values()
    )
    assert b"".join(map(format_json, msgs)) == b"".join(map(_format_clean, msgs))


def test_replay_imports_neither_structlog_nor_yaml(tmp_path: Path) -> None:
    """``hdrd replay --bias`` loads no logging framework and no YAML parser (each costs tens
    of ms of the replay's budget); the daemon's own modules import them where used."""
    cap = tmp_path / "c.bin"
    FakeGyro(profile_frames(simulate_drive("standstill", 0.1, 1, hz=10.0))).write_capture(cap)
    code = (
        "import sys; from hdrd.cli import main; rc = main(['replay', sys.argv[1], '--bias', '0']);"
        "print(rc, sorted(m for m in ('structlog', 'yaml', 'asyncio') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(cap)], capture_output=True, text=True, check=True
    ).stdout
    assert out.splitlines()[-1] == "0 []"
