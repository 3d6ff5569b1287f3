"""hdrd.io.wire.record and `hdrd record`: raw bytes from the port to a capture file, losing nothing."""

from __future__ import annotations

import io
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import array_to_frames
from hdrd.io.wire.record import record
from hdrd.io.wire.sources import SerialReader
from hdrd.sim.fakegyro import FakeGyro
from hdrd.sim.profiles import builtin_profile

WAIT_S = 30.0


def start_record(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "hdrd", "record", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def stop(p: subprocess.Popen[str]) -> str:
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 0, err
    assert "Traceback" not in err
    return err


def test_record_function_on_loop_url() -> None:
    reader = SerialReader("loop://")
    data = bytes(range(256)) * 12  # loop:// holds at most 4096 bytes
    reader.port.write(data)
    out = io.BytesIO()
    res = record(reader, out, seconds=0.3)
    assert out.getvalue() == data and res["bytes"] == len(data) and res["losses"] == 0
    stopped = io.BytesIO()
    res = record(reader, stopped, stop=lambda: True)  # stop at once: still drains the port
    assert res["bytes"] == 0
    reader.close()


def test_record_from_fake_gyro_decodes_to_exactly_the_frames_sent(
    fake_gyro, tmp_path: Path
) -> None:
    prof = builtin_profile("constant", minutes=0.5, hz=50, rate_dps=4.0, lead_in_s=5.0)
    g = fake_gyro(prof, speedup=0, garbage=0.05, crc_errors=0.05, drop=0.02, seed=2)
    out = tmp_path / "cap.bin"
    p = start_record("--port", g.path, "--out", str(out))
    try:
        g.start()  # as fast as possible: waits for record to open the port
        assert g.wait(WAIT_S) and g.error is None
        stop(p)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    arr, st = decode_capture(out.read_bytes())
    assert array_to_frames(arr) == g.sent_frames() and arr.shape[0] == g.injected.frames
    assert st.bad_frames == g.injected.expected_bad_frames > 0
    assert st.garbage_bytes == g.injected.garbage_bytes + 16 * g.injected.crc_errors


@pytest.mark.slow
def test_record_stops_after_seconds(fake_gyro, tmp_path: Path) -> None:
    g = fake_gyro(builtin_profile("standstill", minutes=10, hz=20), speedup=1.0)
    out = tmp_path / "cap.bin"
    p = start_record("--port", g.path, "--out", str(out), "--seconds", "1.0")
    g.start()
    _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 0, err
    arr, st = decode_capture(out.read_bytes())
    assert st.bad_frames == 0 and arr.shape[0] >= 1
    seq = arr["seq"].astype(int)
    assert np.all(np.diff(seq) == 1)  # nothing lost in between
    assert f"to {out}" in err


@pytest.mark.slow
def test_record_survives_a_cable_pull(tmp_path: Path) -> None:
    link = tmp_path / "gyro"
    prof = builtin_profile("standstill", minutes=0.3, hz=50, lead_in_s=0.0)
    g = FakeGyro(prof, speedup=0, link=link, pull_at=[5.0], pull_for=1.0)
    out = tmp_path / "cap.bin"
    with g:
        p = start_record("--port", str(link), "--out", str(out))
        try:
            g.start()
            assert g.wait(WAIT_S) and g.error is None
            err = stop(p)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert "device lost" in err and "device back" in err and "1 device losses" in err
    arr, st = decode_capture(out.read_bytes())
    assert array_to_frames(arr) == g.sent_frames()
    assert st.seq_gaps == 1 and st.lost_frames == g.injected.pulled_frames == 50


def test_record_bad_arguments(tmp_path: Path) -> None:
    cases = [
        (["--port", "loop://", "--out", str(tmp_path / "a"), "--seconds", "0"], 2, "--seconds"),
        (["--port", "nosuch://x", "--out", str(tmp_path / "b")], 2, "unusable"),
        (["--port", "loop://", "--out", str(tmp_path / "no" / "dir" / "c")], 1, "cannot write"),
    ]
    for args, code, text in cases:
        p = start_record(*args)
        _, err = p.communicate(timeout=WAIT_S)
        assert p.returncode == code and text in err and "Traceback" not in err


def test_record_on_a_missing_port_fails_at_once_without_a_file(tmp_path: Path) -> None:
    # Was: exit 0 with an empty capture, the user none the wiser.
    out = tmp_path / "cap.bin"
    p = start_record("--port", str(tmp_path / "absent"), "--out", str(out), "--seconds", "5")
    _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 1, err
    assert err.startswith(f"hdrd record: cannot open {tmp_path / 'absent'}: ")
    assert err.rstrip().endswith("nothing recorded") and len(err.splitlines()) == 1
    assert not out.exists()


def test_record_on_a_port_in_use_fails_at_once(fake_gyro, tmp_path: Path) -> None:
    g = fake_gyro(builtin_profile("standstill", minutes=1), speedup=0)
    with SerialReader(g.path) as holder:  # another program has it (hdrd run)
        assert holder.is_open
        out = tmp_path / "cap.bin"
        p = start_record("--port", g.path, "--out", str(out), "--seconds", "5")
        _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 1 and f"{g.path} is in use by another program" in err
    assert not out.exists()


def test_record_on_a_full_disk_says_so_in_one_line(fake_gyro) -> None:
    # /dev/full: every write fails with ENOSPC. Was: three chained tracebacks.
    g = fake_gyro(builtin_profile("standstill", minutes=2, hz=100), speedup=0)
    p = start_record("--port", g.path, "--out", "/dev/full", "--seconds", "20")
    g.start()
    _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 1, err
    assert "Traceback" not in err and len(err.splitlines()) == 1
    assert err.startswith("hdrd record: cannot write /dev/full: No space left on device;")


def test_record_of_a_silent_port_is_not_a_success(fake_gyro, tmp_path: Path) -> None:
    g = fake_gyro(builtin_profile("standstill", minutes=1), speedup=0)  # never started
    out = tmp_path / "cap.bin"
    p = start_record("--port", g.path, "--out", str(out), "--seconds", "0.5")
    _, err = p.communicate(timeout=WAIT_S)
    assert p.returncode == 1 and "nothing came from" in err and "Traceback" not in err
