"""``hdrd replay``: the daemon's pipeline on a capture, bit-identical to the live daemon."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.cli import main as cli
from hdrd.config import Config
from hdrd.core.calibrate import BiasRecord
from hdrd.core.sensor import SensorModel
from hdrd.daemon.replay import replay_capture
from hdrd.io.files.biasfile import save_bias
from hdrd.io.files.drivelog import read_drive
from hdrd.sim.fakegyro import FakeGyro
from tests.test_daemon import drive_profile, strip_time

WAIT = 30.0


def replay_cli(capsys, *args: str) -> tuple[int, list[dict], str]:
    rc = cli(["replay", *args])
    cap = capsys.readouterr()
    return rc, [json.loads(x) for x in cap.out.splitlines()], cap.err


@pytest.mark.slow
@pytest.mark.parametrize("method", ["hdr", "hdr+"])
def test_replay_matches_the_live_daemon_bit_for_bit_with_faults(
    fake_gyro, tmp_path, capsys, method
):
    profile = drive_profile(seconds=90)
    kw: dict[str, Any] = dict(garbage=0.05, crc_errors=0.05, seed=11)
    g = fake_gyro(profile, speedup=0, **kw)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(WAIT)
    env = dict(os.environ, STATE_DIRECTORY="/nonexistent-hdrd-state")
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hdrd",
            "run",
            "--clock-rate",
            "0",
            "--port",
            g.path,
            "--bias",
            "0.3",
            "--method",
            method,
            "--udp",
            f"127.0.0.1:{rx.getsockname()[1]}",
        ],
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        g.start()
        live = [json.loads(rx.recvfrom(65536)[0]) for _ in range(89)]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=WAIT)
        rx.close()
    assert proc.returncode == 0
    assert live[-1]["bad_frames"] == g.injected.expected_bad_frames > 0
    cap = tmp_path / "cap.bin"
    FakeGyro(profile, **kw).write_capture(cap)  # the same bytes, faults included
    rc, replayed, _ = replay_cli(capsys, str(cap), "--bias", "0.3", "--method", method)
    assert rc == 0
    assert all("time" not in m for m in replayed)
    assert ("zupt" in replayed[-1]) == (method == "hdr+")  # HDR+'s own key: it ran
    assert replayed[:89] == [strip_time(m) for m in live]
    assert len(replayed) == 90  # the last, partial block is flushed at end of input


def test_replay_of_a_fakegyro_capture_follows_its_known_truth(tmp_path, capsys):
    # the built-in "constant" drive: 30 s standstill, then 1 min at 3 deg/s CCW; bias 0.2 deg/s
    cap = tmp_path / "c.bin"
    assert (
        cli(
            [
                "fakegyro",
                "--drive",
                "constant",
                "--rate-dps",
                "3",
                "--minutes",
                "1",
                "--out",
                str(cap),
            ]
        )
        == 0
    )
    capsys.readouterr()
    rc, msgs, _ = replay_cli(capsys, str(cap), "--calibrate-seconds", "30", "--method", "none")
    assert rc == 0
    assert [m["status"] for m in msgs[:30]] == ["calibrating"] * 30
    assert msgs[30]["bias"] == pytest.approx(0.2, abs=0.01)
    steps = msgs[30:]
    assert len(steps) == 60
    # truth: 3 deg/s for 60 s -> yaw 180 deg CCW, compass heading (0 - 180) mod 360
    assert steps[-1]["yaw"] == pytest.approx(180.0, abs=1.0)
    assert steps[-1]["heading"] == pytest.approx(180.0, abs=1.0)
    assert np.mean([m["omega"] for m in steps]) == pytest.approx(3.0, abs=0.02)


def test_record_then_replay_equals_the_stream(fake_gyro, tmp_path, capsys):
    profile = drive_profile(seconds=40)
    g = fake_gyro(profile, speedup=0, garbage=0.02, seed=5)
    cap = tmp_path / "rec.bin"
    rec = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "record", "--port", g.path, "--out", str(cap)],
        stderr=subprocess.PIPE,
    )
    try:
        g.start()
        assert g.wait(WAIT)
    finally:
        rec.send_signal(signal.SIGINT)
        rec.communicate(timeout=WAIT)
    assert rec.returncode == 0
    ref = tmp_path / "ref.bin"
    FakeGyro(profile, garbage=0.02, seed=5).write_capture(ref)
    assert cap.read_bytes() == ref.read_bytes()
    rc, msgs, _ = replay_cli(capsys, str(cap), "--bias", "0.3")
    assert rc == 0 and len(msgs) == 40


def test_replay_text_protocol_equals_binary(tmp_path, capsys):
    profile = drive_profile(seconds=30)
    b, t = tmp_path / "b.bin", tmp_path / "t.txt"
    FakeGyro(profile).write_capture(b)
    FakeGyro(profile, protocol="hdr-text").write_capture(t)
    _, mb, _ = replay_cli(capsys, str(b), "--bias", "0.3")
    _, mt, _ = replay_cli(capsys, str(t), "--bias", "0.3", "--protocol", "hdr-text")
    assert mb == mt and len(mb) == 30


def test_replay_bias_sources(tmp_path, capsys):
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=20)).write_capture(cap)
    bf = tmp_path / "bias.yaml"
    save_bias(bf, BiasRecord(0.31, 0.01, 300, 30.0))
    _, a, _ = replay_cli(capsys, str(cap), "--bias-file", str(bf))
    assert {m["bias"] for m in a} == {0.31}
    cfg = tmp_path / "h.yaml"
    cfg.write_text(f"calibration:\n  bias_file: {bf}\n")
    _, b, _ = replay_cli(capsys, str(cap), "--config", str(cfg))
    assert a == b
    _, c, _ = replay_cli(capsys, str(cap), "--calibrate-seconds", "3")
    assert [m["status"] for m in c[:3]] == ["calibrating"] * 3 and "bias" in c[3]


def test_replay_never_takes_the_machines_bias_file(tmp_path, capsys, monkeypatch):
    # `hdrd run` falls back to $STATE_DIRECTORY/bias.yaml; a replay does not (its lines must
    # not depend on the machine), and its --help no longer claims it does.
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=20)).write_capture(cap)
    empty = tmp_path / "h.yaml"
    empty.write_text("{}\n")
    _, alone, _ = replay_cli(capsys, str(cap), "--config", str(empty))
    state = tmp_path / "state"
    save_bias(state / "bias.yaml", BiasRecord(0.31, 0.01, 300, 30.0))
    monkeypatch.setenv("STATE_DIRECTORY", str(state))
    _, with_state, _ = replay_cli(capsys, str(cap), "--config", str(empty))
    assert with_state == alone and 0.31 not in {m.get("bias") for m in alone}
    with pytest.raises(SystemExit):
        cli(["replay", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "never this machine's $STATE_DIRECTORY or /var/lib/hdrd bias file" in text
    assert "--heading0 DEG compass heading at start, deg (default output.heading0_deg, 0)" in text


def test_replay_errors(tmp_path, capsys):
    rc, _, err = replay_cli(capsys, str(tmp_path / "missing.bin"))
    assert rc == 1 and "cannot read" in err
    bf = tmp_path / "bias.yaml"
    bf.write_text("garbage")
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=5)).write_capture(cap)
    rc, _, err = replay_cli(capsys, str(cap), "--bias-file", str(bf))
    assert rc == 1 and "bias file" in err
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("hdr:\n  c2: .inf\n")
    rc, _, err = replay_cli(capsys, "x", "--config", str(cfg))
    assert rc == 78 and "hdr.c2" in err


def test_convert_capture_to_drive_log(tmp_path, capsys):
    prof = drive_profile(seconds=20)
    cap = tmp_path / "c.bin"
    FakeGyro(prof).write_capture(cap)
    out = tmp_path / "d.csv"
    assert cli(["convert", str(cap), "--out", str(out)]) == 0
    log = read_drive(out)
    assert len(log) == len(prof)
    np.testing.assert_allclose(log.t, prof.t, atol=1e-6)
    np.testing.assert_allclose(log.omega, prof.omega, atol=SensorModel().lsb_dps)
    assert log.temp_c is not None
    np.testing.assert_allclose(log.temp_c, 24.5)


def test_replay_capture_is_pure_and_repeatable(tmp_path):
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=20), crc_errors=0.1, seed=2).write_capture(cap)
    data = Path(cap).read_bytes()
    a = replay_capture(data, Config(), 0.3)
    b = replay_capture(data, Config(), 0.3)
    assert a == b and a[-1]["bad_frames"] > 0


def test_replay_in_chunks_is_replay_whole(tmp_path):
    # hdrd replay feeds the pipeline a chunk of frames at a time and writes each chunk's
    # steps before the next (memory follows the chunk, not the capture): the same messages.
    from hdrd.daemon.replay import replay_steps
    from hdrd.io.wire.capture import decode_capture

    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=60), crc_errors=0.05, garbage=0.05, seed=3).write_capture(cap)
    frames, st = decode_capture(cap.read_bytes())
    for bias, startup in ((0.3, None), (None, 2.5)):
        whole = replay_capture(cap.read_bytes(), Config(), bias, startup)
        for chunk in (1, 7, 100, 10**6):
            got = [
                m
                for msgs in replay_steps(
                    frames, st.bad_before, st.bad_frames, Config(), bias, startup, chunk=chunk
                )
                for m in msgs
            ]
            assert got == whole, chunk


def test_replay_of_what_is_not_a_capture_says_so(tmp_path, capsys):
    # Was: exit 0 and no output at all.
    notes = tmp_path / "notes.txt"
    notes.write_text("shopping list\n" * 100)
    rc, msgs, err = replay_cli(capsys, str(notes), "--bias", "0.3")
    assert rc == 1 and msgs == [] and len(err.splitlines()) == 1
    assert err.startswith(f"hdrd replay: no valid frames in {notes} (")
    assert "--protocol hdr-text" in err
    # A capture read with the wrong --protocol: the error names the other one.
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=5)).write_capture(cap)
    rc, msgs, err = replay_cli(capsys, str(cap), "--bias", "0.3", "--protocol", "hdr-text")
    assert rc == 1 and msgs == [] and "(--protocol hdr-bin)" in err
    rc, msgs, err = replay_cli(capsys, str(cap), "--bias", "0.3")
    assert rc == 0 and len(msgs) == 5
    # 20 MB of the sync pattern and nothing else: ten million candidates, no frame.
    a55a = tmp_path / "a55a.bin"
    a55a.write_bytes(b"\xa5\x5a" * 10_000_000)
    rc, msgs, err = replay_cli(capsys, str(a55a), "--bias", "0.3")
    assert rc == 1 and msgs == [] and "no valid frames" in err and "9999993 bad frames" in err
    assert cli(["convert", str(notes), "--out", str(tmp_path / "d.csv")]) == 1
    assert "no valid frames" in capsys.readouterr().err


def test_replay_refuses_what_is_not_a_regular_file(tmp_path, capsys):
    fifo = tmp_path / "cap.fifo"
    os.mkfifo(fifo)  # would wait for a writer for ever
    for path, why in ((fifo, "is a FIFO"), ("/dev/zero", "is a character device")):
        rc, msgs, err = replay_cli(capsys, str(path), "--bias", "0.3")
        assert rc == 1 and msgs == [] and f"cannot read {path}: {why}" in err
        assert cli(["convert", str(path), "--out", str(tmp_path / "d.csv")]) == 1
        assert why in capsys.readouterr().err


@pytest.mark.parametrize("bias", ["nan", "inf", "-inf", "1e308", "3.5"])
def test_replay_bias_must_be_finite_and_within_the_limit(tmp_path, capsys, bias):
    cap = tmp_path / "c.bin"
    FakeGyro(drive_profile(seconds=5)).write_capture(cap)
    rc, msgs, err = replay_cli(capsys, str(cap), f"--bias={bias}")
    assert rc == 78 and msgs == []
    assert err.startswith(f"hdrd: config error in command line: --bias = {float(bias)!r}: must be")
    assert "calibration.max_bias_dps" in err
    bf = tmp_path / "bias.yaml"
    bf.write_text("bias_dps: 1.0e+308\nstd_dps: 0.01\nn: 10\nduration_s: 1.0\ntime: 0.0\n# end\n")
    rc, msgs, err = replay_cli(capsys, str(cap), "--bias-file", str(bf))
    assert rc == 1 and msgs == [] and "calibration.max_bias_dps" in err
