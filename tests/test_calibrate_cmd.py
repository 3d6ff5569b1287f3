"""``hdrd calibrate`` as a user runs it (hdrd/commands/calibrate.py): a process reading a fake gyro
on a real pty, or the simulated gyro, writing the bias file.

No timings are asserted; the waits are generous bounds that only fail a hung command.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.io.files.biasfile import load_bias
from hdrd.sim.profiles import builtin_profile, profile_frames

WAIT = 120.0


def calibrate(*args: str, timeout: float = WAIT, **kw: Any) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(
        [sys.executable, "-m", "hdrd", "calibrate", *args],
        capture_output=True,
        timeout=timeout,
        **kw,
    )


def test_one_glitched_timestamp_does_not_end_the_window(fake_gyro, tmp_path: Path) -> None:
    # One CRC-valid frame whose device clock reads 30 min ahead: the window is still 5 s of
    # samples, not "done" after 2 s with duration_s 1802.
    frames = profile_frames(builtin_profile("standstill", minutes=1, bias_dps=0.42, lead_in_s=0))
    frames["t_us"][20] = (int(frames["t_us"][20]) + 1_800_000_000) % 2**32
    g = fake_gyro(frames, speedup=0)
    g.start()
    bias_file = tmp_path / "bias.yaml"
    p = calibrate("--port", g.path, "--seconds", "5", "--bias-file", str(bias_file))
    assert p.returncode == 0, p.stderr.decode()
    rec = load_bias(bias_file)
    assert rec.duration_s == pytest.approx(5.0, abs=0.15)
    assert rec.n == pytest.approx(50, abs=2) and rec.bias_dps == pytest.approx(0.42, abs=0.03)
    # The parser drops it: its clock disagrees with its sequence number (docs/protocol.md,
    # "Sequence and clock"); the window's own glitch rule, behind it: test_clocks.py.


def test_a_bias_file_that_is_a_fifo_is_written_through(fake_gyro, tmp_path: Path) -> None:
    # `--bias-file FIFO`: the record goes to the FIFO's reader; the FIFO is not replaced by a
    # regular file (as the atomic rename did).
    import os
    import stat
    import threading

    frames = profile_frames(builtin_profile("standstill", minutes=1, bias_dps=0.42, lead_in_s=0))
    g = fake_gyro(frames, speedup=0)
    g.start()
    fifo = tmp_path / "bias.yaml"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    p = calibrate("--port", g.path, "--seconds", "2", "--bias-file", str(fifo))
    reader.join(WAIT)
    assert p.returncode == 0, p.stderr.decode()
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    assert got and b"bias_dps: 0.4" in got[0] and got[0].endswith(b"# end\n")


def test_the_noise_parameters_are_recorded_beside_the_bias(fake_gyro, tmp_path: Path) -> None:
    # The window's white noise and output step go into the bias file for HDR+; a 10 s window
    # cannot show how the bias wanders (that needs 10 minutes), and the result line says so.
    frames = profile_frames(builtin_profile("standstill", minutes=1, bias_dps=0.42, lead_in_s=0))
    g = fake_gyro(frames, speedup=0)
    g.start()
    bias_file = tmp_path / "bias.yaml"
    p = calibrate("--port", g.path, "--seconds", "10", "--bias-file", str(bias_file))
    assert p.returncode == 0, p.stderr.decode()
    rec = load_bias(bias_file)
    assert rec.noise is not None and rec.noise.source == "recorded" and not rec.noise.known()
    # the profile's 0.05 deg/s per sample at 10 Hz: N = 0.05 / sqrt(10), read from 100 samples
    assert rec.noise.white_dps_per_rthz == pytest.approx(0.05 / 10**0.5, rel=0.35)
    assert "noise:\n  white_dps_per_rthz:" in bias_file.read_text()
    assert b"noise recorded: white" in p.stdout and b"10 min or more" in p.stdout


def test_calibrate_refuses_when_the_vehicle_moves(fake_gyro, tmp_path: Path) -> None:
    bias_file = tmp_path / "bias.yaml"
    g = fake_gyro(builtin_profile("constant", minutes=1, rate_dps=12.0, lead_in_s=2), speedup=0)
    g.start()
    p = calibrate("--port", g.path, "--seconds", "5", "--bias-file", str(bias_file))
    assert p.returncode == 1
    assert b"moved" in p.stderr
    assert not bias_file.exists()


@pytest.mark.slow
def test_a_steady_rotation_is_refused_naming_the_limit(fake_gyro, tmp_path: Path) -> None:
    # 10 deg/s, perfectly steady: spread, trend and excursion all pass; the size does not.
    g = fake_gyro(builtin_profile("constant", minutes=1, rate_dps=10.0, lead_in_s=0), speedup=0)
    g.start()
    bias_file = tmp_path / "bias.yaml"
    p = calibrate("--port", g.path, "--seconds", "5", "--bias-file", str(bias_file))
    err = p.stderr.decode()
    assert p.returncode == 1 and not bias_file.exists()
    assert "beyond the +/-3 deg/s" in err and "calibration.max_bias_dps" in err
    # Configurable: a gyro with a larger bias range is told so in the config.
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("calibration:\n  max_bias_dps: 15\n")
    g2 = fake_gyro(builtin_profile("constant", minutes=1, rate_dps=10.0, lead_in_s=0), speedup=0)
    g2.start()
    p = calibrate(
        "--config", str(cfg), "--port", g2.path, "--seconds", "5", "--bias-file", str(bias_file)
    )
    assert p.returncode == 0, p.stderr.decode()
    assert load_bias(bias_file).bias_dps == pytest.approx(10.2, abs=0.1)


@pytest.mark.slow
def test_no_device_gives_up_and_says_so(fake_gyro, tmp_path: Path) -> None:
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("calibration:\n  no_data_timeout_s: 1.0\n")
    bias_file = tmp_path / "bias.yaml"
    # No such device at all ...
    p = calibrate("--config", str(cfg), "--port", str(tmp_path / "ttyNONE"), "--bias-file",
                  str(bias_file), timeout=60)  # fmt: skip
    err = p.stderr.decode()
    assert p.returncode == 1 and not bias_file.exists()
    assert "no data from" in err and "for 1 s" in err and "calibration.no_data_timeout_s" in err
    assert "bias file not written" in err.splitlines()[-1]
    # said at once, plainly: not "device lost" with pyserial's message
    none = tmp_path / "ttyNONE"
    assert f"{none} does not exist; waiting up to 1 s for it to appear" in err.splitlines()
    assert "device lost" not in err
    # ... and a device that is there but sends nothing.
    g = fake_gyro(builtin_profile("standstill", minutes=1), speedup=0)  # never started
    p = calibrate("--config", str(cfg), "--port", g.path, "--bias-file", str(bias_file),
                  timeout=60)  # fmt: skip
    assert p.returncode == 1 and b"no data from" in p.stderr and not bias_file.exists()


@pytest.mark.slow
def test_piped_to_head_still_writes_the_bias_file(tmp_path: Path) -> None:
    # `hdrd calibrate | head -1`: the reader leaves after the first line. The bias file was
    # promised: the measurement goes on, the file is written and the result said on stderr.
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("simulate:\n  drive: standstill\n  speedup: 10\n")
    bias_file = tmp_path / "bias.yaml"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "calibrate", "--simulate", "--config", str(cfg),
         "--seconds", "5", "--bias-file", str(bias_file)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    proc.stdout.close()  # what head -1 does
    err = proc.stderr.read().decode()
    rc = proc.wait(timeout=WAIT)
    assert first.startswith(b"calibrating:")
    assert rc == 0, err
    assert load_bias(bias_file).n > 0
    assert "written to" in err and "Traceback" not in err


def test_a_write_that_fails_says_where_in_one_line(tmp_path: Path) -> None:
    # /proc takes no new file: the temporary file beside the bias file cannot be made.
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("simulate:\n  drive: standstill\n  speedup: 100\n")
    p = calibrate("--simulate", "--config", str(cfg), "--seconds", "1",
                  "--bias-file", "/proc/hdrd-bias.yaml")  # fmt: skip
    last = p.stderr.decode().strip().splitlines()[-1]
    assert p.returncode == 1
    assert last == (
        "hdrd calibrate: cannot write /proc/hdrd-bias.yaml: No such file or directory "
        "(its temporary file in /proc); bias file not written"
    )


@pytest.mark.slow
def test_bad_seconds_is_a_config_error() -> None:
    for value in ("nan", "0", "-3", "1e308"):
        p = calibrate("--simulate", "--seconds", value, timeout=60)
        err = p.stderr.decode()
        assert p.returncode == 78, err
        assert err.startswith(f"hdrd: config error in command line: --seconds = {float(value)!r}")
        assert len(err.splitlines()) == 1


def test_the_port_of_a_running_daemon_is_refused_at_once(fake_gyro, tmp_path: Path) -> None:
    # The daemon holds the port (exclusively); calibrate must not steal half its frames.
    frames = profile_frames(builtin_profile("standstill", minutes=5, lead_in_s=0))
    g = fake_gyro(frames, speedup=20)
    from hdrd.io.wire.sources import SerialSource

    with SerialSource(g.path) as holder:  # the first opener, as `hdrd run` opens it
        g.start()
        deadline = time.monotonic() + 30
        while not hasattr(holder.recv(0.5), "t_us"):
            assert time.monotonic() < deadline, "the holder got no frame"
        bias_file = tmp_path / "bias.yaml"
        p = calibrate("--port", g.path, "--seconds", "3", "--bias-file", str(bias_file))
        err = p.stderr.decode()
        assert p.returncode == 1, err
        assert f"{g.path} is in use by another program" in err and not bias_file.exists()
        assert len(err.splitlines()) == 1
        got = [holder.recv(0.5) for _ in range(20)]  # the holder still reads every frame
        assert all(hasattr(f, "t_us") for f in got)
        seq = np.array([f.seq for f in got])
        assert np.all(np.diff(seq) == 1)
