"""``hdrd run`` and ``hdrd calibrate`` as a user runs them: a process reading a fake gyro on a
real pty, publishing over real UDP sockets, talking to a real NOTIFY_SOCKET, taking signals.

No timings are asserted; waits are generous upper bounds that only fail a hung daemon.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.net.formats import nmea_checksum
from hdrd.io.wire.codec import frames_to_array
from hdrd.sim.profiles import builtin_profile
from tests.test_calibrate_cmd import calibrate

WAIT = 30.0  # upper bound for anything to happen; only a hung daemon reaches it


class Udp:
    """A UDP receiver on 127.0.0.1 collecting datagrams."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.addr = f"127.0.0.1:{self.port}"

    def recv_json(self, timeout: float = WAIT) -> dict[str, Any]:
        self.sock.settimeout(timeout)
        data, _ = self.sock.recvfrom(65536)
        return json.loads(data)

    def messages(self, until, timeout: float = WAIT) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv_json(max(0.1, deadline - time.monotonic()))
            out.append(m)
            if until(out):
                return out
        raise AssertionError(f"condition not met; got {len(out)} messages, last {out[-1:]}")

    def lines(self, n: int, timeout: float = WAIT) -> list[bytes]:
        out: list[bytes] = []
        self.sock.settimeout(timeout)
        while len(out) < n:
            data, _ = self.sock.recvfrom(65536)
            out.extend(line for line in data.split(b"\r\n") if line)
        return out

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def udp() -> Iterator[Any]:
    made: list[Udp] = []

    def make() -> Udp:
        u = Udp()
        made.append(u)
        return u

    yield make
    for u in made:
        u.close()


class Daemon:
    def __init__(
        self, args: list[str], env: dict[str, str] | None = None, stdout: Any = subprocess.PIPE
    ) -> None:
        e = dict(os.environ)
        e.pop("NOTIFY_SOCKET", None)
        e.pop("WATCHDOG_USEC", None)
        e["STATE_DIRECTORY"] = e.get("STATE_DIRECTORY_TEST", "/nonexistent-hdrd-state")
        e.update(env or {})
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hdrd", "run", "--log-format", "json", *args],
            stdout=stdout,
            stderr=subprocess.PIPE,
            env=e,
        )

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def stop(self) -> tuple[int, bytes, bytes]:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=WAIT)
        return self.proc.returncode, out or b"", err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate(timeout=WAIT)


@pytest.fixture
def daemon() -> Iterator[Any]:
    made: list[Daemon] = []

    def make(*args: str, **kw: Any) -> Daemon:
        d = Daemon(list(args), **kw)
        made.append(d)
        return d

    yield make
    for d in made:
        d.kill()


def events(stderr: bytes) -> list[dict[str, Any]]:
    out = []
    for line in stderr.decode().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass
    return out


def expected_messages(
    frames: np.ndarray, bias: float, heading0: float = 0.0
) -> list[dict[str, Any]]:
    """What the HDR core says the daemon must publish for these frames (without time)."""
    p = Pipeline(PipelineConfig(heading0_deg=heading0, setup=MethodSetup(bias=given_bias(bias))))
    from hdrd.io.wire.codec import array_to_frames

    out: list[dict[str, Any]] = []
    for f in array_to_frames(frames):
        out.extend(p.feed(f))
    return out


def drive_profile(seconds: float = 60.0, seed: int = 3) -> DriveLog:
    """Straight with a drift, a left turn and a right turn; raw rate incl. a 0.3 deg/s bias."""
    hz = 10.0
    t = np.arange(int(seconds * hz)) / hz
    truth = np.where((t > 20) & (t < 26), 15.0, 0.0) - np.where((t > 40) & (t < 43), 30.0, 0.0)
    rng = np.random.default_rng(seed)
    omega = truth + 0.3 + 0.002 * t + rng.normal(0, 0.05, t.shape[0])
    return DriveLog(t=t, omega=omega, omega_truth=truth, temp_c=np.full(t.shape[0], 24.5))


def strip_time(m: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in m.items() if k != "time"}


def test_run_publishes_hdr_steps_over_udp_nmea_and_stdout(fake_gyro, daemon, udp):
    g = fake_gyro(drive_profile(), speedup=0)
    js, nm = udp(), udp()
    d = daemon(
        "--clock-rate",
        "0",
        "--port",
        g.path,
        "--bias",
        "0.3",
        "--udp",
        js.addr,
        "--nmea-udp",
        nm.addr,
        "--nmea-ths",
        "--stdout",
        "--heading0",
        "45",
    )
    g.start()
    got = js.messages(lambda ms: len(ms) >= 59)
    sentences = nm.lines(3 * 59)
    rc, out, err = d.stop()
    assert rc == 0, err.decode()
    assert g.wait(WAIT)
    exp = expected_messages(frames_to_array(g.sent_frames()), 0.3, 45.0)
    assert [strip_time(m) for m in got] == [strip_time(m) for m in exp[:59]]
    assert all(isinstance(m["time"], float) for m in got)
    assert {m["status"] for m in got} == {"ok", "turning"}
    assert got[0]["temp"] == pytest.approx(24.5)
    # stdout carries the same lines (plus the partial last block flushed at exit)
    lines = [json.loads(x) for x in out.splitlines()]
    assert [strip_time(m) for m in lines[:59]] == [strip_time(m) for m in got]
    # NMEA: valid checksums; ROT negative while turning left (omega > 0 = CCW = to port)
    by_kind: dict[str, list[list[str]]] = {}
    for s in sentences:
        body, _, cs = s.decode().partition("*")
        assert s.startswith(b"$") and nmea_checksum(body[1:]) == cs
        fields = body[1:].split(",")
        by_kind.setdefault(fields[0], []).append(fields[1:])
    assert set(by_kind) == {"HNHDT", "HNROT", "HNTHS"}
    rot = [float(f[0]) for f in by_kind["HNROT"]]
    omega = [m["omega"] for m in got]
    left = [r for r, w in zip(rot, omega) if w > 5]
    right = [r for r, w in zip(rot, omega) if w < -5]
    assert left and all(r < 0 for r in left)
    assert right and all(r > 0 for r in right)
    hdt = [float(f[0]) for f in by_kind["HNHDT"]]
    assert hdt == pytest.approx([round(m["heading"], 2) for m in got], abs=0.006)


def test_startup_calibration_without_a_bias_file(fake_gyro, daemon, udp, tmp_path):
    g = fake_gyro(builtin_profile("standstill", minutes=0.5, bias_dps=-0.6, lead_in_s=0), speedup=0)
    u = udp()
    d = daemon("--clock-rate", "0", "--port", g.path, "--udp", u.addr)
    g.start()
    got = u.messages(lambda ms: len(ms) >= 5)
    rc, _, err = d.stop()
    assert rc == 0
    assert got[0]["status"] == "calibrating" and "heading" not in got[0] and "bias" not in got[0]
    assert got[1]["bias"] == pytest.approx(-0.6, abs=0.05)
    names = [e["event"] for e in events(err)]
    assert "calibrated" in names and names[0] == "start"


@pytest.mark.slow
def test_sd_notify_ready_status_watchdog(fake_gyro, daemon, udp, tmp_path):
    path = str(tmp_path / "notify.sock")
    ns = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    ns.bind(path)
    ns.settimeout(WAIT)
    try:
        g = fake_gyro(drive_profile(), speedup=5)
        u = udp()
        d = daemon(
            "--clock-rate",
            "5",
            "--port",
            g.path,
            "--bias",
            "0.3",
            "--udp",
            u.addr,
            env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000"},
        )
        g.start()
        seen: list[str] = []
        while not (
            any(s.startswith("READY=1") for s in seen) and sum(s == "WATCHDOG=1" for s in seen) >= 3
        ):
            seen.append(ns.recv(4096).decode())
        assert any(s.startswith("STATUS=") for s in seen)
        rc, _, _ = d.stop()
        while "STOPPING=1" not in seen:
            seen.append(ns.recv(4096).decode())
        assert rc == 0
        assert seen.index("READY=1") < seen.index("STOPPING=1")
    finally:
        ns.close()


@pytest.mark.slow
def test_unplug_and_replug_reports_stale_and_resumes(fake_gyro, daemon, udp, tmp_path):
    link = tmp_path / "gyro"
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(
        "device:\n  stale_after_s: 0.5\n  reconnect_min_s: 0.1\n  reconnect_max_s: 0.5\n"
    )
    g = fake_gyro(
        builtin_profile(
            "constant", minutes=2, rate_dps=2.0, bias_dps=0.0, noise_dps=0.0, lead_in_s=0
        ),
        speedup=4,
        link=link,
        pull_at=[12.0],
        pull_for=3.0,
    )
    u = udp()
    d = daemon(
        "--clock-rate",
        "4",
        "--config",
        str(cfg),
        "--port",
        str(link),
        "--bias",
        "0",
        "--udp",
        u.addr,
    )
    g.start()
    got = u.messages(
        lambda ms: (
            any("gap_s" in m for m in ms)
            and len(ms) > 5 + [i for i, m in enumerate(ms) if "gap_s" in m][0]
        )
    )
    rc, _, err = d.stop()
    assert rc == 0
    stale = [m for m in got if m["status"] == "stale"]
    assert stale, "no stale report while the cable was out"
    steps = [m for m in got if m["status"] != "stale"]
    nums = [m["step"] for m in steps]
    assert nums == sorted(nums) and len(set(nums)) == len(nums)
    k = next(i for i, m in enumerate(steps) if "gap_s" in m)
    assert steps[k]["gap_s"] > 0.5
    yaws = [m["yaw"] for m in steps]
    # a constant 2 deg/s CCW turn: yaw keeps growing by about 2 deg a step, no jump back to 0
    assert all(0 < b - a < 3.0 for a, b in zip(yaws, yaws[1:]))
    names = [e["event"] for e in events(err)]
    assert "device_lost" in names and "device_back" in names
    assert d.proc.returncode == 0


@pytest.mark.slow
def test_sighup_reloads_keeping_heading_and_rejects_bad_config(fake_gyro, daemon, udp, tmp_path):
    cfg = tmp_path / "hdrd.yaml"
    u1, u2 = udp(), udp()
    cfg.write_text(f"output:\n  udp: ['{u1.addr}']\n  heading0_deg: 0\n")
    g = fake_gyro(
        builtin_profile(
            "constant", minutes=5, rate_dps=1.0, bias_dps=0.0, noise_dps=0.0, lead_in_s=0
        ),
        speedup=5,
    )
    d = daemon("--clock-rate", "5", "--config", str(cfg), "--port", g.path, "--bias", "0")
    g.start()
    first = u1.messages(lambda ms: len(ms) >= 3)
    cfg.write_text(f"output:\n  udp: ['{u2.addr}']\n  heading0_deg: 0\n")
    d.signal(signal.SIGHUP)
    after = u2.messages(lambda ms: len(ms) >= 3)
    # the new destination gets the steps; yaw and heading carry on from where they were
    assert after[0]["step"] > first[-1]["step"]
    assert after[0]["yaw"] > first[-1]["yaw"]
    assert after[0]["heading"] == pytest.approx((0.0 - after[0]["yaw"]) % 360)
    cfg.write_text("output:\n  heading0_deg: 400\n")
    d.signal(signal.SIGHUP)
    more = u2.messages(lambda ms: len(ms) >= 4)  # still publishing with the old config
    assert more[-1]["heading"] == pytest.approx((0.0 - more[-1]["yaw"]) % 360)
    rc, _, err = d.stop()
    assert rc == 0
    ev = events(err)
    assert any(e["event"] == "config_reloaded" for e in ev)
    failed = [e for e in ev if e["event"] == "config_reload_failed"]
    assert failed and "output.heading0_deg" in failed[0]["error"]


@pytest.mark.slow
def test_a_sighup_that_changes_heading0_keeps_the_heading(fake_gyro, daemon, udp, tmp_path):
    """A standing vehicle's heading never moves by itself: output.heading0_deg is the heading
    at start, and a reload that changes it keeps the heading (and says so in the log). It
    used to jump by the difference (2.61 -> 93.25 deg)."""
    cfg = tmp_path / "hdrd.yaml"
    u = udp()
    cfg.write_text(f"output:\n  udp: ['{u.addr}']\n  heading0_deg: 2.5\n")
    g = fake_gyro(builtin_profile("standstill", minutes=5, bias_dps=0.0, noise_dps=0.0), speedup=5)
    d = daemon("--clock-rate", "5", "--config", str(cfg), "--port", g.path, "--bias", "0")
    g.start()
    before = u.messages(lambda ms: len(ms) >= 2)
    assert {m["heading"] for m in before} == {2.5}
    cfg.write_text(f"output:\n  udp: ['{u.addr}']\n  heading0_deg: 93.25\n")
    d.signal(signal.SIGHUP)
    after = u.messages(lambda ms: len(ms) >= 4)
    rc, _, err = d.stop()
    assert rc == 0
    ev = events(err)
    assert [e["source"] for e in ev if e["event"] == "config_reloaded"] == [str(cfg)]
    assert {m["heading"] for m in after} == {2.5}, [m["heading"] for m in after]
    kept = [e for e in ev if e["event"] == "config_reload_partial"]
    assert [(e["key"], e["kept"]) for e in kept] == [("output.heading0_deg", 2.5)]


def test_dead_udp_peers_do_not_stop_the_daemon(fake_gyro, daemon, udp):
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    dead = f"127.0.0.1:{closed.getsockname()[1]}"
    closed.close()  # nothing listens there: ICMP port unreachable -> ECONNREFUSED
    g = fake_gyro(drive_profile(), speedup=0)
    u = udp()
    d = daemon(
        "--clock-rate",
        "0",
        "--port",
        g.path,
        "--bias",
        "0.3",
        "--udp",
        dead,
        "--udp",
        "no-such-host.invalid:9",
        "--udp",
        u.addr,
        "--nmea-udp",
        dead,
    )
    g.start()
    got = u.messages(lambda ms: len(ms) >= 59)
    rc, _, err = d.stop()
    assert rc == 0 and [m["step"] for m in got] == list(range(59))
    assert b"Traceback" not in err
    # At stop, each destination's counters are logged: what failed, and why.
    stats = {(e["output"], e["dest"]): e for e in events(err) if e["event"] == "output_udp_stats"}
    assert set(stats) == {
        ("udp", dead),
        ("udp", "no-such-host.invalid:9"),
        ("udp", u.addr),
        ("nmea_udp", dead),
    }
    good = stats[("udp", u.addr)]
    assert good["level"] == "info" and good["errors"] == 0 and good["sent"] >= 59
    refused = stats[("udp", dead)]
    assert refused["level"] == "warning" and refused["by_error"].get("ECONNREFUSED", 0) >= 1
    assert stats[("nmea_udp", dead)]["by_error"].get("ECONNREFUSED", 0) >= 1
    unresolved = stats[("udp", "no-such-host.invalid:9")]
    assert unresolved["level"] == "warning" and unresolved["by_error"]["resolve"] >= 1
    assert unresolved["sent"] == 0 and unresolved["dropped"] >= 59
    assert events(err)[-1]["event"] == "stop"


@pytest.mark.slow
def test_sigterm_exits_zero(fake_gyro, daemon, udp):
    g = fake_gyro(drive_profile(), speedup=1)
    u = udp()
    d = daemon("--port", g.path, "--bias", "0.3", "--udp", u.addr)
    g.start()
    u.messages(lambda ms: len(ms) >= 1)
    rc, _, err = d.stop()
    assert rc == 0
    assert events(err)[-1]["event"] == "stop"


def test_stdout_closed_by_reader_ends_cleanly():
    p = subprocess.run(
        f"{sys.executable} -m hdrd run --simulate --speedup 50 --bias 0.2 | head -n 3",
        shell=True,
        capture_output=True,
        timeout=120,
    )
    assert len(p.stdout.splitlines()) == 3
    assert b"Traceback" not in p.stderr
    assert b"output_closed" in p.stderr


def test_bad_config_exits_78(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("hdr:\n  tau: -2\n")
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--config", str(cfg)], capture_output=True, timeout=60
    )
    assert p.returncode == 78
    lines = p.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and "hdr.tau" in lines[0] and "-2" in lines[0]
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--udp", "nohost"], capture_output=True, timeout=60
    )
    assert p.returncode == 78 and "output.udp" in p.stderr.decode()


@pytest.mark.slow
def test_calibrate_writes_bias_file_the_daemon_uses(fake_gyro, daemon, udp, tmp_path):
    bias_file = tmp_path / "state" / "bias.yaml"
    g = fake_gyro(
        builtin_profile("standstill", minutes=1, bias_dps=0.42, noise_dps=0.05, lead_in_s=0),
        speedup=0,
    )
    g.start()
    p = calibrate("--port", g.path, "--seconds", "5", "--bias-file", str(bias_file))
    assert p.returncode == 0, p.stderr.decode()
    assert b"written to" in p.stdout
    assert oct(bias_file.stat().st_mode & 0o777) == "0o644"
    from hdrd.io.files.biasfile import load_bias

    rec = load_bias(bias_file)
    assert rec.bias_dps == pytest.approx(0.42, abs=0.02) and rec.duration_s == pytest.approx(
        5.0, abs=0.2
    )
    g2 = fake_gyro(drive_profile(), speedup=0)
    u = udp()
    d = daemon(
        "--clock-rate", "0", "--port", g2.path, "--bias-file", str(bias_file), "--udp", u.addr
    )
    g2.start()
    got = u.messages(lambda ms: len(ms) >= 2)
    d.stop()
    assert got[0]["bias"] == rec.bias_dps and got[0]["status"] != "calibrating"


def test_corrupt_bias_file_is_refused(tmp_path):
    bias_file = tmp_path / "bias.yaml"
    bias_file.write_text("bias_dps: 0.3\nstd_dps: 0.0\n")  # truncated: no trailer
    p = subprocess.run(
        [sys.executable, "-m", "hdrd", "run", "--simulate", "--bias-file", str(bias_file)],
        capture_output=True,
        timeout=60,
    )
    assert p.returncode == 1 and b"truncated" in p.stderr


@pytest.mark.slow
def test_sighup_switches_gpsd_aiding_on(fake_gyro, daemon, udp, tmp_path):
    """gpsd settings are reloaded too: a SIGHUP that enables gpsd makes the running daemon
    connect to it and ask for its JSON reports (?WATCH), without a restart."""
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(20.0)
    port = srv.getsockname()[1]
    cfg = tmp_path / "hdrd.yaml"
    u = udp()
    cfg.write_text(f"output:\n  udp: ['{u.addr}']\n")
    g = fake_gyro(drive_profile(), speedup=5)
    d = daemon("--clock-rate", "5", "--config", str(cfg), "--port", g.path, "--bias", "0.3")
    g.start()
    u.messages(lambda ms: len(ms) >= 2)
    cfg.write_text(
        f"output:\n  udp: ['{u.addr}']\ngpsd:\n  enabled: true\n  host: 127.0.0.1\n"
        f"  port: {port}\n  bias_window_s: 30.0\n"
    )
    d.signal(signal.SIGHUP)
    try:
        conn, _ = srv.accept()
        conn.settimeout(20.0)
        request = conn.recv(1024)
        conn.close()
    finally:
        srv.close()
    assert request.startswith(b"?WATCH=") and b'"json":true' in request.replace(b" ", b"")
    rc, _, err = d.stop()
    assert rc == 0
    ev = [e for e in events(err) if e["event"] == "gpsd_reconfigured"]
    assert ev and ev[0]["enabled"] is True and ev[0]["port"] == port
