"""hdrd.sim.fakegyro: the pty fake ADC, its fault injection, and the ``hdrd fakegyro`` command."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.core.sensor import SensorModel
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import Frame, array_to_frames
from hdrd.io.wire.parser import Parser
from hdrd.io.wire.sources import SerialSource
from hdrd.sim.fakegyro import FakeGyro
from hdrd.sim.profiles import builtin_profile

WAIT_S = 20.0


def read_all(src: SerialSource, g: FakeGyro) -> list[Frame]:
    """Frames from src until the gyro is done and the port is quiet."""
    out: list[Frame] = []
    end = time.monotonic() + WAIT_S
    while time.monotonic() < end:
        item = src.recv(0.2)
        if isinstance(item, Frame):
            out.append(item)
        elif item is None and g.done:
            break
        else:
            assert item is None, item
    assert g.done and g.error is None
    return out


def edge_missing(g: FakeGyro) -> int:
    """Frames not delivered before the first / after the last delivered one: no reader can
    see those as a sequence gap."""
    idx = np.flatnonzero(g.delivered)
    return int(idx[0] + (len(g.delivered) - 1 - idx[-1])) if idx.size else len(g.delivered)


def profile(minutes: float = 0.2, hz: float = 50.0) -> DriveLog:
    return builtin_profile("constant", minutes=minutes, hz=hz, rate_dps=-7.5, lead_in_s=2.0)


def test_pty_and_link(fake_gyro, tmp_path: Path) -> None:
    link = tmp_path / "gyro"
    g = fake_gyro(profile(), link=link)
    assert g.path and stat.S_ISCHR(os.stat(g.path).st_mode)
    assert os.path.islink(link) and os.readlink(link) == g.path
    g.close()
    assert not os.path.lexists(link)
    g.close()  # idempotent


def test_link_never_replaces_or_deletes_what_is_not_a_symlink(tmp_path: Path) -> None:
    # Was: `hdrd fakegyro --link notes.txt` replaced the regular file, then deleted it.
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me\n")
    (tmp_path / "dir").mkdir()
    for path in (notes, tmp_path / "dir"):
        with pytest.raises(FileExistsError, match="not a symlink"):
            FakeGyro(profile(), link=path).open()
    assert notes.read_text() == "keep me\n" and (tmp_path / "dir").is_dir()
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "fakegyro", "--link", str(notes), "--speedup", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 1 and p.stdout == ""
    assert p.stderr.strip() == (
        f"hdrd fakegyro: cannot open a pty or the link {notes}: "
        "exists and is not a symlink; refusing to replace it"
    )
    assert notes.read_text() == "keep me\n"


def test_link_is_removed_only_while_it_is_ours(tmp_path: Path) -> None:
    # An old link (from an earlier fake) is re-pointed; if someone else re-points it while we
    # run, closing leaves theirs alone.
    link = tmp_path / "gyro"
    os.symlink("/dev/null", link)
    g = FakeGyro(profile(), link=link).open()
    assert os.readlink(link) == g.path
    os.unlink(link)
    os.symlink("/dev/null", link)  # another program's now
    g.close()
    assert os.readlink(link) == "/dev/null"


@pytest.mark.parametrize("protocol", ["hdr-bin", "hdr-text"])
def test_injected_faults_match_the_parser_counts(fake_gyro, protocol: str) -> None:
    g = fake_gyro(
        profile(), protocol=protocol, speedup=0, garbage=0.1, crc_errors=0.1, drop=0.05, seed=4
    )
    with SerialSource(g.path, protocol=protocol) as src:
        g.start()
        got = read_all(src, g)
        st = src.stats
    inj = g.injected
    assert got == g.sent_frames() and len(got) == inj.frames
    assert inj.garbage_events and inj.crc_errors and inj.dropped  # each fault happened
    assert st.bad_frames == inj.expected_bad_frames
    assert st.lost_frames == inj.dropped + inj.crc_errors - edge_missing(g)
    assert inj.frames + inj.crc_errors + inj.dropped == len(g.frames)
    good_bytes = sum(len(g._frame_wire(k)) for k in np.flatnonzero(g.delivered))
    assert st.garbage_bytes == src.link.bytes_read - good_bytes
    if protocol == "hdr-bin":
        assert st.garbage_bytes == inj.garbage_bytes + 16 * inj.crc_errors


def test_capture_file_is_reproducible_and_decodes_to_the_frames_sent(tmp_path: Path) -> None:
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    kw = dict(garbage=0.2, crc_errors=0.1, drop=0.1, pull_at=[5.0], pull_for=2.0, seed=11)
    ga = FakeGyro(profile(), **kw)  # type: ignore[arg-type]
    ga.write_capture(a)
    gb = FakeGyro(profile(), **kw)  # type: ignore[arg-type]
    gb.write_capture(b)
    assert a.read_bytes() == b.read_bytes()
    arr, st = decode_capture(a.read_bytes())
    assert array_to_frames(arr) == ga.sent_frames()
    inj = ga.injected
    assert inj.pulls == 1 and inj.pulled_frames == 100  # 2 s at 50 Hz
    assert st.bad_frames == inj.expected_bad_frames
    assert st.lost_frames == inj.dropped + inj.crc_errors + inj.pulled_frames - edge_missing(ga)
    t = arr["t_us"] / 1e6
    assert not np.any((t >= 5.0) & (t < 7.0))  # the pull is a hole in device time
    c = tmp_path / "c.bin"
    FakeGyro(profile(), **{**kw, "seed": 12}).write_capture(c)  # type: ignore[arg-type]
    assert c.read_bytes() != a.read_bytes()


def test_real_time_pacing_with_speedup(fake_gyro) -> None:
    g = fake_gyro(profile(minutes=0.05, hz=20), speedup=20.0)  # 5 s of device time
    with SerialSource(g.path) as src:
        g.start()
        got = read_all(src, g)
    assert got == array_to_frames(g.frames) and g.injected.unread_frames == 0


def test_real_time_starts_with_its_reader(fake_gyro) -> None:
    """A real-time drive waits for its first reader: one that opens the port a moment after
    the start (a user typing the next command) gets the drive from its first frame. Once it
    runs, frames due while nobody reads are lost, as a real device's are."""
    g = fake_gyro(profile(minutes=0.05, hz=50), speedup=50.0)
    g.start()
    assert not g.wait(0.5)  # nobody reads: the drive has not started
    assert g.injected.frames == 0 and g.injected.unread_frames == 0
    with SerialSource(g.path) as src:
        got = read_all(src, g)
    assert got == array_to_frames(g.frames) and g.injected.unread_frames == 0


def test_as_fast_as_possible_waits_for_a_reader(fake_gyro) -> None:
    g = fake_gyro(profile(minutes=0.02), speedup=0)
    g.start()
    assert not g.wait(0.3)  # nobody reads: it waits, it does not throw frames away
    assert g.injected.frames == 0
    with SerialSource(g.path) as src:
        got = read_all(src, g)
    assert got == array_to_frames(g.frames)


@pytest.mark.slow
def test_pull_on_request(fake_gyro, tmp_path: Path) -> None:
    link = tmp_path / "g"
    g = fake_gyro(profile(minutes=0.5, hz=20), speedup=20.0, link=link)
    with SerialSource(str(link), reconnect_min_s=0.02, reconnect_max_s=0.05) as src:
        g.start()
        kinds: list[str] = []
        end = time.monotonic() + WAIT_S
        n = 0
        while time.monotonic() < end and not (
            g.done and kinds[-2:] == ["DeviceLost", "DeviceBack"]
        ):
            item = src.recv(0.1)
            if isinstance(item, Frame):
                n += 1
                if n == 20:
                    g.pull(0.2)
            elif item is not None:
                kinds.append(type(item).__name__)
        assert kinds == ["DeviceLost", "DeviceBack"]
        assert g.injected.pulls == 1 and g.injected.pulled_frames >= 1
    g.stop()


def test_frames_array_profile_and_bad_arguments() -> None:
    arr = np.zeros(
        3, dtype=[("seq", "<u2"), ("t_us", "<u4"), ("rate", "<u2"), ("ref", "<u2"), ("temp", "<i2")]
    )
    arr["seq"] = [1, 2, 3]
    arr["t_us"] = [2**32 - 10, 5, 20]  # a wrap: device seconds still increase
    g = FakeGyro(arr)
    assert g.t_s.tolist() == pytest.approx([0.0, 15e-6, 30e-6])
    for bad in (
        dict(garbage=1.5),
        dict(drop=-0.1),
        dict(speedup=-1.0),
        dict(pull_for=0.0),
        dict(protocol="nmea"),
    ):
        with pytest.raises(ValueError):
            FakeGyro(arr, **bad)


# --------------------------------------------------------------------------- the command


def hdrd(*args: str, **kw: Any) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hdrd", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def test_cli_out_file(tmp_path: Path) -> None:
    out = tmp_path / "cap.bin"
    p = hdrd(
        "fakegyro",
        "--drive",
        "constant",
        "--rate-dps",
        "3",
        "--minutes",
        "0.05",
        "--hz",
        "20",
        "--crc-errors",
        "0.1",
        "--seed",
        "5",
        "--out",
        str(out),
    )
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    arr, st = decode_capture(out.read_bytes())
    assert arr.shape[0] + st.bad_frames == 20 * (30 + 3)  # lead-in 30 s + 3 s
    assert "crc_errors" in err


def test_cli_pty_prints_paths_serves_frames_and_exits_0_on_sigterm(tmp_path: Path) -> None:
    link = tmp_path / "gyro"
    p = hdrd(
        "fakegyro",
        "--drive",
        "standstill",
        "--minutes",
        "30",
        "--hz",
        "50",
        "--speedup",
        "5",
        "--link",
        str(link),
    )
    try:
        assert p.stdout is not None
        path = p.stdout.readline().strip()
        assert p.stdout.readline().strip() == str(link)
        assert os.readlink(link) == path
        with SerialSource(str(link)) as src:
            frames: list[Frame] = []
            end = time.monotonic() + WAIT_S
            while len(frames) < 20 and time.monotonic() < end:
                item = src.recv(0.5)
                if isinstance(item, Frame):
                    frames.append(item)
            assert len(frames) == 20
            seqs = [f.seq for f in frames]
            assert seqs == list(range(seqs[0], seqs[0] + 20))
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=WAIT_S)
        assert p.returncode == 0, err
        assert "interrupted" in err and not os.path.lexists(link)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--drive", "moon"], "unknown"),
        (["--drive", "standstill", "--garbage", "2"], "probability"),
        (["--drive", "standstill", "--speedup", "-1"], "speedup"),
    ],
)
def test_cli_bad_arguments(args: list[str], message: str, tmp_path: Path) -> None:
    p = hdrd("fakegyro", *args, "--out", str(tmp_path / "x.bin"))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2 and message in err and "Traceback" not in err


def test_parser_sees_the_constant_rate_of_the_profile(tmp_path: Path) -> None:
    """The fake gyro's truth survives the wire: counts -> deg/s gives rate + bias."""
    out = tmp_path / "c.bin"
    prof = builtin_profile(
        "constant", minutes=0.1, hz=10, rate_dps=-7.5, bias_dps=0.25, noise_dps=0.0, lead_in_s=1.0
    )
    FakeGyro(prof).write_capture(out)
    p = Parser()
    frames = p.feed(out.read_bytes())
    omega = SensorModel().to_dps_array(np.array([f.rate for f in frames]), 0)
    lsb = SensorModel().lsb_dps
    assert np.all(np.abs(omega[:10] - 0.25) <= lsb / 2 + 1e-12)
    assert np.all(np.abs(omega[10:] - (-7.5 + 0.25)) <= lsb / 2 + 1e-12)
    assert len(frames) == 70 and p.stats.frames == 70
