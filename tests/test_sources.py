"""hdrd.io.wire.sources: serial (loop://, real ptys, cable pulls) and simulated sources: frames and
link events. The raw link underneath (reopening, backoff, sockets): test_serialport.py."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hdrd.core.sensor import SensorModel
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.clocks import ManualClock
from hdrd.io.wire.codec import FRAME_DTYPE, Frame, array_to_frames, encode, encode_bin
from hdrd.io.wire.sources import DeviceBack, DeviceLost, EndOfInput, SerialSource, Source
from hdrd.io.wire.tracker import ParserStats
from hdrd.sim.profiles import ProfileError, builtin_profile, load_profile
from hdrd.sim.source import SimulatedSource

WAIT_S = 20.0  # upper bound for anything that should happen "soon" (never a timing assertion)


def frames_array(n: int, t0_us: int = 0, step_us: int = 100_000, seq0: int = 0) -> np.ndarray:
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = (seq0 + np.arange(n)) & 0xFFFF
    arr["t_us"] = (t0_us + np.arange(n, dtype=np.int64) * step_us) % 2**32
    arr["rate"] = (32768 + np.arange(n) * 7) & 0xFFFF
    arr["ref"] = 0
    arr["temp"] = np.where(np.arange(n) % 3 == 0, -32768, 2000 + np.arange(n) % 100)
    return arr


def collect(
    src: Source, until: int | None = None, done: Callable[[], bool] | None = None
) -> tuple[list[Frame], list[object]]:
    """recv until ``until`` frames arrived, EndOfInput, or ``done()`` and silence."""
    frames: list[Frame] = []
    events: list[object] = []
    end = time.monotonic() + WAIT_S
    while time.monotonic() < end:
        item = src.recv(0.2)
        if isinstance(item, Frame):
            frames.append(item)
            if until is not None and len(frames) >= until:
                break
        elif item is None:
            if done is not None and done():
                break
        else:
            events.append(item)
            if isinstance(item, EndOfInput):
                break
    return frames, events


# --------------------------------------------------------------------------- serial: loop://


def test_loop_url_delivers_frames_and_timeouts_mean_no_data() -> None:
    src: SerialSource
    with SerialSource("loop://") as src:
        assert isinstance(src, Source)
        assert src.recv(0.01) is None  # nothing yet: not the end, not an error
        sent = array_to_frames(frames_array(50))
        data = b"".join(encode_bin(f) for f in sent)
        src.port.write(data[:96])
        src.port.write(b"\x00\xa5\x5a garbage" + data[96:])
        got, events = collect(src, until=50)
        assert got == sent and events == []
        assert src.recv(0.01) is None
        st = src.stats
        assert st.frames == 50 and st.bad_frames == 1 and st.garbage_bytes == 11
        assert src.link.bytes_read == len(data) + 11
    assert src.closed
    src.close()  # idempotent
    assert src.recv(0.01) is None


def test_loop_url_text_protocol() -> None:
    sent = array_to_frames(frames_array(20))
    with SerialSource("loop://", protocol="hdr-text") as src:
        src.port.write(b"".join(encode(f, "hdr-text") for f in sent))
        got, _ = collect(src, until=20)
    assert got == sent


def test_bad_frames_are_reported_per_frame_as_in_a_capture() -> None:
    """stats.bad_frames when a frame is handed out = bad frames before it in the byte stream,
    whatever the chunking: what decode_capture's bad_before says, so live and replay agree."""
    rng = np.random.default_rng(5)
    parts = []
    for f in array_to_frames(frames_array(200)):
        b = bytearray(encode_bin(f))
        if rng.random() < 0.2:
            b[5] ^= 0x10
        parts.append(bytes(b))
    data = b"".join(parts)
    arr, cap = decode_capture(data)
    with SerialSource("loop://") as src:
        for i in range(0, len(data), 37):
            src.port.write(data[i : i + 37])
        seen = []
        for _ in range(arr.shape[0]):
            f = src.recv(1.0)
            assert isinstance(f, Frame)
            seen.append(src.stats.bad_frames)
        assert src.recv(0.01) is None
        assert src.stats.bad_frames == cap.bad_frames
    assert seen == cap.bad_before.tolist()
    assert cap.bad_frames > 10


def test_unusable_url_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="unusable serial port URL"):
        SerialSource("nosuchscheme://x")


# --------------------------------------------------------------------------- serial: ptys


def test_pty_eof_is_device_lost_once_then_quiet(tmp_path: Path) -> None:
    master, slave = os.openpty()
    # Through a link removed at the unplug: a freed /dev/pts/N may be handed to another
    # process at once, and reopening it must not look like the gyro coming back.
    path = tmp_path / "gyro"
    path.symlink_to(os.ttyname(slave))
    os.close(slave)
    try:
        with SerialSource(str(path), reconnect_min_s=0.05, reconnect_max_s=0.1) as src:
            sent = array_to_frames(frames_array(5))
            os.write(master, b"".join(encode_bin(f) for f in sent))
            got, _ = collect(src, until=5)
            assert got == sent
            assert src.recv(0.05) is None  # silent device: no data, still connected
            path.unlink()
            os.close(master)
            master = -1
            item = None
            for _ in range(200):  # bounded: only a hung source gets here
                item = src.recv(0.05)
                if item is not None:
                    break
            assert isinstance(item, DeviceLost) and item.reason
            assert src.port is None and src.link.lost == 1
            # The pty is gone for good: it keeps trying, never raises, reports nothing new.
            for _ in range(5):
                assert src.recv(0.05) is None
            assert src.link.open_failures >= 1
    finally:
        if master >= 0:
            os.close(master)


def test_missing_device_at_start_then_plugged_in(tmp_path: Path) -> None:
    link = tmp_path / "gyro"
    with SerialSource(str(link), reconnect_min_s=0.02, reconnect_max_s=0.05) as src:
        item = src.recv(0.01)
        assert isinstance(item, DeviceLost) and item.reason
        assert src.recv(0.05) is None
        master, slave = os.openpty()
        try:
            os.symlink(os.ttyname(slave), link)
            os.close(slave)
            item = src.recv(WAIT_S)
            assert isinstance(item, DeviceBack)
            f = Frame(7, 700, 1234, 0, None)
            os.write(master, encode_bin(f))
            assert src.recv(WAIT_S) == f
            assert src.link.reconnects == 1
        finally:
            os.close(master)


def test_recv_never_waits_longer_than_asked_while_lost(tmp_path: Path) -> None:
    """Backoff sleeps happen inside recv, bounded by its timeout (checked on a manual clock)."""
    clock = ManualClock()
    src = SerialSource(
        str(tmp_path / "none"), reconnect_min_s=1.0, reconnect_max_s=8.0, clock=clock
    )
    assert isinstance(src.recv(0.5), DeviceLost)
    for timeout in (0.3, 0.5, 2.0, 0.0, 5.0, 10.0, 10.0, 10.0):
        before = clock.now
        assert src.recv(timeout) is None
        assert clock.now - before <= timeout + 1e-9
    # Backoff doubled up to the maximum: failures at 0, 1, 3, 7, 15, 23, 31, ...
    assert src.link.open_failures >= 5
    waits = [w for w in clock.slept if w > 0]
    assert max(waits) <= 8.0 + 1e-9
    src.close()


def test_end_to_end_real_pty_written_by_the_fake_gyro(fake_gyro) -> None:
    prof = builtin_profile("constant", minutes=0.5, hz=50, rate_dps=12.5, seed=3)
    g = fake_gyro(prof, speedup=0, garbage=0.05, crc_errors=0.05, drop=0.02, seed=9)
    with SerialSource(g.path) as src:
        g.start()
        got, events = collect(src, done=lambda: g.done)
        assert g.wait(WAIT_S) and g.error is None
        assert events == []
        inj = g.injected
        assert got == g.sent_frames() and len(got) == inj.frames > 0
        st = src.stats
        assert st.bad_frames == inj.expected_bad_frames > 0
        assert st.garbage_bytes == inj.garbage_bytes + 16 * inj.crc_errors
        assert st.lost_frames == inj.dropped + inj.crc_errors
    # The counts decode to the profile's truth: 12.5 deg/s (+ bias) after the lead-in.
    omega = SensorModel().to_dps_array(np.array([f.rate for f in got]), 0)
    t = np.array([f.t_us for f in got]) / 1e6
    moving = omega[t >= 30.0].mean() - omega[t < 30.0].mean()
    assert moving == pytest.approx(12.5, abs=0.02)


@pytest.mark.slow
def test_cable_pull_reports_lost_then_back_and_frames_resume(fake_gyro, tmp_path: Path) -> None:
    prof = builtin_profile("standstill", minutes=0.5, hz=100, lead_in_s=0.0)
    link = tmp_path / "hdrd-gyro"
    g = fake_gyro(prof, speedup=0, link=link, pull_at=[5.0, 12.0], pull_for=0.3)
    with SerialSource(str(link), reconnect_min_s=0.05, reconnect_max_s=0.2) as src:
        g.start()
        last = array_to_frames(g.frames[-1:])[0]
        frames: list[Frame] = []
        events: list[tuple[object, int]] = []
        end = time.monotonic() + 3 * WAIT_S
        while time.monotonic() < end and not (frames and frames[-1] == last):
            item = src.recv(0.2)
            if isinstance(item, Frame):
                frames.append(item)
            elif item is not None:
                events.append((item, len(frames)))
        assert g.wait(WAIT_S) and g.error is None
        kinds = [type(e).__name__ for e, _ in events]
        assert kinds == ["DeviceLost", "DeviceBack", "DeviceLost", "DeviceBack"]
        assert g.injected.pulls == 2
        # Every frame written intact was read, in order; the pulls' frames are a seq gap.
        assert frames == g.sent_frames()
        assert frames[-1].seq == (len(prof) - 1) & 0xFFFF
        assert src.stats.seq_gaps == 2 and src.stats.lost_frames == g.injected.pulled_frames == 60
        t_lost = [frames[n - 1].t_us / 1e6 for e, n in events if isinstance(e, DeviceLost)]
        assert t_lost == pytest.approx([4.99, 11.99])
        assert src.link.lost == 2 and src.link.reconnects == 2


# --------------------------------------------------------------------------- replay


# --------------------------------------------------------------------------- simulated


def test_simulated_source_as_fast_as_possible() -> None:
    with SimulatedSource("constant", minutes=0.1, hz=10, rate_dps=5.0, speedup=0) as src:
        got, events = collect(src)
        assert events == [EndOfInput()] and src.recv(0) is None
    assert len(got) == len(src.profile) == 360
    assert got == array_to_frames(src.frames)
    assert src.stats.frames == 360
    assert [f.seq for f in got] == list(range(360))
    assert got[-1].temp_c == pytest.approx(25.0)


def test_simulated_source_paced_on_a_clock() -> None:
    clock = ManualClock()
    t = np.arange(0, 2.0, 0.1)
    log = DriveLog(t=t, omega=np.full(t.shape, 3.0))
    src = SimulatedSource(profile=log, speedup=4.0, clock=clock)
    out = []
    while not isinstance(item := src.recv(0.01), EndOfInput):
        if item is not None:
            assert isinstance(item, Frame)
            out.append((item, clock.now))
    assert len(out) == 20 and out[-1][1] == pytest.approx(1.9 / 4)
    assert all(f.temp_cc is None for f, _ in out)
    assert all(w <= 0.01 + 1e-12 for w in clock.slept)
    with pytest.raises(ValueError):
        SimulatedSource("standstill", minutes=0.01, speedup=-1)


def test_simulated_drive_from_the_simulator() -> None:
    log = load_profile("city", minutes=0.2, seed=2, hz=10)
    assert len(log) > 100 and log.omega_truth is not None
    src = SimulatedSource(profile=log, speedup=0)
    got, events = collect(src)
    assert events == [EndOfInput()] and len(got) == len(log)
    with pytest.raises(ProfileError):
        load_profile("no-such-road", minutes=1)


def test_sources_satisfy_the_protocol_and_close_idempotently(tmp_path: Path) -> None:
    srcs = [
        SerialSource("loop://"),
        SimulatedSource("standstill", minutes=0.01, speedup=0),
    ]
    for s in srcs:
        assert isinstance(s, Source) and isinstance(s.stats, ParserStats)
        s.close()
        s.close()
        assert s.recv(0) is None


def test_a_frame_held_for_a_look_past_it_comes_before_device_lost(tmp_path: Path) -> None:
    # The last frame before the unplug has a sync pattern inside (seq 0x5AA5): the parser
    # holds it until the next frame's start shows it was real. The unplug ends the input, so
    # it is handed out then, before DeviceLost, with its bad-frame count.
    master, slave = os.openpty()
    path = tmp_path / "gyro"
    path.symlink_to(os.ttyname(slave))
    os.close(slave)
    sent = array_to_frames(frames_array(3, seq0=0x5AA2)) + [Frame(0x5AA5, 300_000, 5, 0, None)]
    try:
        with SerialSource(str(path), reconnect_min_s=0.05, reconnect_max_s=0.1) as src:
            os.write(master, b"\xa5\x5a\x00" + b"".join(encode_bin(f) for f in sent))
            got, _ = collect(src, until=3)
            assert got == sent[:3] and src.recv(0.1) is None  # the fourth is held
            path.unlink()
            os.close(master)
            master = -1
            items = []
            for _ in range(200):
                item = src.recv(0.05)
                if item is not None:
                    items.append(item)
                if isinstance(item, DeviceLost):
                    break
            assert items[0] == sent[3] and isinstance(items[1], DeviceLost) and len(items) == 2
            assert src.bad_frames == 1 and src.stats.frames == 4
    finally:
        if master >= 0:
            os.close(master)


def test_end_input_hands_out_a_held_frame(tmp_path: Path) -> None:
    # At shutdown the daemon ends the input: a frame held back for a look past its end is
    # decided as at the end of a capture (and replays the same way).
    master, slave = os.openpty()
    path = tmp_path / "gyro"
    path.symlink_to(os.ttyname(slave))
    os.close(slave)
    held = Frame(0x5AA5, 100_000, 7, 0, None)
    try:
        with SerialSource(str(path)) as src:
            os.write(master, encode_bin(held))
            deadline = time.monotonic() + 5.0
            while src.parser.pending < 16 and time.monotonic() < deadline:
                assert src.recv(0.05) is None
            assert src.parser.pending == 16
            src.end_input()
            assert src.recv(0.0) == held and src.recv(0.0) is None
            assert src.stats.frames == 1 and src.parser.pending == 0
    finally:
        os.close(master)
