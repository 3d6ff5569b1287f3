"""hdrd and the real gpsd, both directions.

GPS -> hdrd: gpsfake (gpsd-clients) replays an NMEA log we write ($GPGGA/$GPRMC, a drive
through north, a GPS outage) into a real gpsd; :class:`hdrd.io.net.gpsd.GpsdClient` receives the
TPV reports, :class:`hdrd.daemon.aiding.GpsAiding` switches aided -> dead-reckoning -> aided and
the heading stays continuous; and a real ``hdrd run --gpsd`` does the same end to end.

hdrd -> gpsd: gpsd reading hdrd's NMEA over ``udp://`` reports the heading as ATT. What
gpsd 3.22 (Debian 12) does with our sentences: $--HDT becomes ATT ``heading``, but only
from talkers its packet lexer accepts (GP/GN/GL, HC, II/IN, ...): $HN... sentences are
dropped before decoding, hence ``output.nmea_talker: II`` (docs/protocol.md, "NMEA 0183 and
gpsd"). $--THS and $--ROT give no ATT in 3.22 (newer gpsd decode THS). A held heading (status
stale) reaches gpsd as no HDT at all.

Skipped, with the reason, only where gpsd/gpsfake cannot run. Every process started is
killed in a ``finally``; no timings are asserted (waits are upper bounds for a hung peer).
"""

from __future__ import annotations

import functools
import itertools
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.core.angles import wrap180
from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup
from hdrd.core.sensor import SensorModel
from hdrd.daemon.aiding import AIDED, DEAD_RECKONING, AidingConfig, GpsAiding
from hdrd.daemon.pipeline import Pipeline
from hdrd.daemon.stepper import PipelineConfig
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.net.formats import nmea_checksum, parse_nmea
from hdrd.io.net.gpsd import GpsdClient
from hdrd.io.net.gpsdjson import WATCH_COMMAND, Fix
from hdrd.io.net.publish import UdpNmeaPublisher
from tests.test_aiding import on_message

WAIT = 30.0  # upper bound for anything to happen; only a hung peer reaches it
KNOT_MPS = 1852.0 / 3600.0

# -- gpsd availability -----------------------------------------------------------------------


@functools.cache
def _gpsd_problem() -> str | None:
    if shutil.which("gpsd") is None:
        return "gpsd is not installed (Debian: apt-get install gpsd gpsd-clients; .ci/run installs it as root)"
    return None


@functools.cache
def _gpsfake_problem() -> str | None:
    if _gpsd_problem():
        return _gpsd_problem()
    exe = shutil.which("gpsfake")
    if exe is None:
        return "gpsfake is not installed (Debian package gpsd-clients)"
    try:
        r = subprocess.run([exe, "-h"], capture_output=True, timeout=WAIT, check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"gpsfake cannot run: {e}"
    if r.returncode != 0:
        return f"gpsfake cannot run: {r.stderr.decode(errors='replace').strip()[-200:]}"
    return None


@pytest.fixture
def need_gpsd() -> None:
    if problem := _gpsd_problem():
        pytest.skip(problem)


@pytest.fixture
def need_gpsfake() -> None:
    if problem := _gpsfake_problem():
        pytest.skip(problem)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Proc:
    """A process in its own session (gpsfake starts gpsd as its child); stop() ends the
    whole group, SIGTERM then SIGKILL."""

    def __init__(self, argv: list[str], log: Path, env: dict[str, str] | None = None) -> None:
        self.argv = argv
        self.log = log
        self._f = log.open("wb")
        self.p = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._f,
            start_new_session=True,
            env=env,
        )

    def stop(self) -> int | None:
        if self.p.poll() is None:
            for sig, wait in ((signal.SIGTERM, 3.0), (signal.SIGKILL, WAIT)):
                try:
                    os.killpg(self.p.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.p.wait(wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
        else:  # the leader is gone; its children (gpsd) may not be
            try:
                os.killpg(self.p.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        self._f.close()
        return self.p.returncode

    def stderr(self) -> str:
        return self.log.read_text(errors="replace")[-2000:]


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Callable[..., Proc]]:
    made: list[Proc] = []

    def start(argv: list[str], env: dict[str, str] | None = None) -> Proc:
        p = Proc(argv, tmp_path / f"proc{len(made)}.log", env)
        made.append(p)
        return p

    try:
        yield start
    finally:
        for p in made:
            p.stop()


# -- an NMEA log ---------------------------------------------------------------------------------


def sentence(body: str) -> str:
    return f"${body}*{nmea_checksum(body)}\r\n"


def _ddmm(deg: float, width: int) -> str:
    d = int(abs(deg))
    return f"{d:0{width}d}{(abs(deg) - d) * 60:07.4f}"


def nmea_log(
    course: list[float | None], speed_mps: float = 15.0, lat: float = 48.1, lon: float = 11.5
) -> str:
    """One $GPGGA + $GPRMC per second from 12:00:00 on 2025-11-21; course[k] None = no fix
    in second k (GGA quality 0, RMC status V). Positions advance along the course."""
    out = []
    for k, c in enumerate(course):
        hms = f"12{k // 60:02d}{k % 60:02d}.00"
        if c is None:
            out.append(sentence(f"GPGGA,{hms},,,,,0,00,,,M,,M,,"))
            out.append(sentence(f"GPRMC,{hms},V,,,,,,,211125,,,N"))
            continue
        la = f"{_ddmm(lat, 2)},{'N' if lat >= 0 else 'S'}"
        lo = f"{_ddmm(lon, 3)},{'E' if lon >= 0 else 'W'}"
        out.append(sentence(f"GPGGA,{hms},{la},{lo},1,09,0.9,520.0,M,47.0,M,,"))
        out.append(
            sentence(f"GPRMC,{hms},A,{la},{lo},{speed_mps / KNOT_MPS:.3f},{c:.2f},211125,,,A")
        )
        lat += speed_mps * math.cos(math.radians(c)) / 111_320.0
        lon += speed_mps * math.sin(math.radians(c)) / (111_320.0 * math.cos(math.radians(lat)))
    return "".join(out)


def tod(fix: Fix) -> int | None:
    """Seconds since 12:00:00 of the log (gpsd may get the date wrong; the time is ours)."""
    return None if fix.time is None else round(fix.time % 86400.0) - 12 * 3600


def test_nmea_log_is_valid():
    text = nmea_log([10.0, None, 359.99])
    lines = text.splitlines()
    assert len(lines) == 6
    for line in lines:
        parse_nmea(line)  # checksums right
    assert lines[3].startswith("$GPRMC,120001.00,V")
    assert parse_nmea(lines[5])[1][7] == "359.99"


# -- GPS -> hdrd: gpsfake ----------------------------------------------------------------------------


def outage_drive() -> tuple[list[float], list[float | None]]:
    """True course per second (compass deg) and what the GPS reports (None: outage)."""
    truth = []
    c = 340.0
    for k in range(70):
        if 15 <= k < 25:
            c += 4.0  # right turn through north: 340 -> 20
        elif 36 <= k < 51:
            c -= 2.0  # left turn inside the outage: 20 -> 350
        truth.append(c % 360.0)
    gps = [None if 35 <= k < 50 else truth[k] for k in range(70)]
    return truth, gps


def run_gpsfake(
    procs: Callable[..., Proc], tmp_path: Path, log_text: str, port: int, cycle: float
) -> Proc:
    log = tmp_path / "drive.nmea"
    log.write_text(log_text)
    # -n: gpsd opens the fake device at once (else sentences written before a client's
    # WATCH are lost); -1: the log once; -c: seconds between sentences.
    return procs(
        [
            shutil.which("gpsfake") or "gpsfake",
            "-1",
            "-n",
            "-q",
            "-c",
            str(cycle),
            "-P",
            str(port),
            str(log),
        ]
    )


def collect_fixes(client: GpsdClient, until: Callable[[list[Any]], bool], proc: Proc) -> list[Any]:
    reports: list[Any] = []
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        reports.extend(client.poll_reports())
        if until(reports):
            return reports
        time.sleep(0.01)
    raise AssertionError(
        f"gpsd did not deliver; {len(reports)} reports, last {reports[-3:]}; gpsfake: {proc.stderr()}"
    )


@dataclass(frozen=True)
class Frame:
    t_us: int
    rate: int
    ref: int = 0
    temp_c: float | None = None


def gyro_steps(
    truth: list[float], bias_true: float, bias_given: float, seed: int = 2
) -> list[dict[str, Any]]:
    """The real pipeline's step messages for a gyro that saw the true course changes
    (10 Hz samples, raw = true CCW rate + bias + noise); step k ends at t = k + 1."""
    rng = np.random.default_rng(seed)
    rate = [-wrap180(b - a) for a, b in itertools.pairwise(truth)]  # CCW, deg/s per second
    raw = np.repeat(rate, 10) + bias_true + rng.normal(0, 0.05, 10 * len(rate))
    counts = SensorModel().to_counts(np.append(raw, raw[-1]))
    p = Pipeline(PipelineConfig(setup=MethodSetup(bias=given_bias(bias_given))))
    out: list[dict[str, Any]] = []
    for i, c in enumerate(counts):
        out.extend(p.feed(Frame(i * 100_000, int(c))))
    return out


@pytest.mark.slow
def test_gpsfake_drive_through_an_outage(need_gpsfake, procs, tmp_path):
    truth, gps = outage_drive()
    port = free_port()
    client = GpsdClient("127.0.0.1", port, reconnect_min_s=0.05, reconnect_max_s=0.2)
    try:
        client.poll_reports()
        fake = run_gpsfake(procs, tmp_path, nmea_log(gps), port, cycle=0.02)
        last = len(gps) - 1
        reports = collect_fixes(
            client, lambda rs: any(isinstance(r, Fix) and tod(r) == last for r in rs), fake
        )
    finally:
        client.close()
    assert client.stats.bad_lines == 0, client.stats.errors
    assert client.version is not None and client.version.proto_major == 3
    fixes = [r for r in reports if isinstance(r, Fix) and tod(r) is not None]
    by_second: dict[int, list[Fix]] = {}
    for f in fixes:
        by_second.setdefault(tod(f) or 0, []).append(f)
    # what we wrote is what gpsd reports: course and speed while fixed, mode 1 in the outage
    good = [k for k, c in enumerate(gps) if c is not None]
    seen = [k for k in good if any(f.track_deg is not None for f in by_second.get(k, []))]
    assert len(seen) >= 0.8 * len(good), f"TPV with course for {len(seen)} of {len(good)} seconds"
    for k in seen:
        f = next(f for f in by_second[k] if f.track_deg is not None)
        assert f.mode >= 2 and f.track_deg is not None
        assert abs(wrap180(f.track_deg - (gps[k] or 0.0))) < 0.01, (k, f)
        assert f.speed_mps == pytest.approx(15.0, abs=0.01)
    assert any(f.mode == 1 for k in range(35, 50) for f in by_second.get(k, [])), (
        "no no-fix TPV in the outage"
    )
    assert all(f.mode < 2 for k in range(36, 50) for f in by_second.get(k, []))

    # GpsAiding on the gyro's steps and these fixes, in their order: a fix of second k is
    # received at k + 0.3 s, the step ending at k is published at k + 0.05 s
    steps = gyro_steps(truth, bias_true=0.4, bias_given=0.35)
    events: list[tuple[float, int, Any]] = [(tod(f) + 0.3, 0, f) for f in fixes]  # type: ignore[operator]
    events += [(m["t"] + 0.05, 1, m) for m in steps]
    events.sort(key=lambda e: (e[0], e[1]))
    aiding = GpsAiding(AidingConfig(min_speed_mps=5.0))
    pub: list[dict[str, Any]] = []
    hdr: list[float] = []
    for now, kind, item in events:
        if kind == 0:
            aiding.on_fix(item, now)
        else:
            out, _ = on_message(aiding, item, now)
            pub.append(out)
            hdr.append(item["heading"])
    modes = [m["mode"] for m in pub]
    first = modes.index(AIDED)
    runs = [modes[first]] + [b for a, b in itertools.pairwise(modes[first:]) if a != b]
    assert runs == [AIDED, DEAD_RECKONING, AIDED]
    dr = [i for i, m in enumerate(modes) if m == DEAD_RECKONING and i > first]
    # gpsd reports the first no-fix second late (or not): at most the fix age later
    assert 35 <= pub[dr[0]]["t"] <= 38.5 and 50 <= pub[dr[-1] + 1]["t"] <= 52
    k_truth = {round(m["t"]): truth[round(m["t"])] for m in pub if round(m["t"]) < len(truth)}
    for i, m in enumerate(pub):
        k = round(m["t"])
        if i >= first + 3 and k in k_truth:
            # aided through north and back, dead reckoning through the outage's turn
            assert abs(wrap180(m["heading"] - k_truth[k])) < 3.0, (
                k,
                m["heading"],
                k_truth[k],
                m["mode"],
            )
        if i > first:
            # continuous: changes like the HDR heading, up to the smooth alignment
            d_pub = wrap180(m["heading"] - pub[i - 1]["heading"])
            d_hdr = wrap180(hdr[i] - hdr[i - 1])
            assert abs(d_pub - d_hdr) < 1.5, (k, d_pub, d_hdr)
    assert {round(m["heading"]) % 360 for m in pub if m["mode"] == AIDED} & {
        358,
        359,
        0,
        1,
        2,
    }  # crossed north


@pytest.mark.slow
def test_gpsfake_a_receiver_without_a_fix_another_course_and_a_glitch(
    need_gpsfake, procs, tmp_path
):
    """Two receivers through one real gpsd: A drives course 90 (one glitch, course 270, at
    second 25); B has no fix for 20 s, then a fix with course 180. The gyro is straight on
    90. Aiding follows A (the first with a fix) alone: B's TPVs without a fix do not end
    aiding, B's course is never used, A's glitch is rejected, the heading stays on 90."""
    n = 45
    course_a: list[float | None] = [90.0] * n
    course_a[25] = 270.0
    logs = {
        "a.nmea": nmea_log(course_a),
        "b.nmea": nmea_log([None] * 20 + [180.0] * (n - 20), lat=47.0),
    }
    for name, text in logs.items():
        (tmp_path / name).write_text(text)
    port = free_port()
    client = GpsdClient("127.0.0.1", port, reconnect_min_s=0.05, reconnect_max_s=0.2)
    try:
        client.poll_reports()
        fake = procs(
            [shutil.which("gpsfake") or "gpsfake", "-1", "-n", "-q", "-c", "0.05", "-P", str(port)]
            + [str(tmp_path / name) for name in logs]
        )

        def a_done(rs: list[Any]) -> bool:
            return any(isinstance(r, Fix) and r.track_deg == 90.0 and tod(r) == n - 1 for r in rs)

        reports = collect_fixes(client, a_done, fake)
    finally:
        client.close()
    assert client.stats.bad_lines == 0, client.stats.errors
    fixes = [r for r in reports if isinstance(r, Fix)]
    devices = {f.device for f in fixes}
    assert len(devices) == 2, devices  # gpsd reported both receivers
    assert any(f.mode < 2 for f in fixes)  # B's TPVs without a fix
    assert any(f.track_deg == 180.0 for f in fixes)  # B's course
    # each TPV received at (its second, or the last second seen) + 0.3 s, in gpsd's order;
    # the gyro's step k ends at k + 1
    aiding = GpsAiding()
    steps = gyro_steps([90.0] * (n + 2), bias_true=0.2, bias_given=0.2)
    events: list[tuple[float, int, Any]] = []
    k = 0
    for i, f in enumerate(fixes):
        k = tod(f) if tod(f) is not None else k  # type: ignore[assignment]
        events.append((k + 0.3 + i * 1e-6, 0, f))
    events += [(m["t"], 1, m) for m in steps]
    events.sort(key=lambda e: (e[0], e[1]))
    pub: list[dict[str, Any]] = []
    for now, kind, item in events:
        if kind == 0:
            aiding.on_fix(item, now)
        else:
            pub.append(on_message(aiding, item, now)[0])
    first = next(i for i, m in enumerate(pub) if m["mode"] == AIDED)
    after = pub[first:]
    assert all(abs(wrap180(m["heading"] - 90.0)) < 1.0 for m in after), [
        round(m["heading"], 1) for m in after
    ]
    assert all(m.get("gps_course") in (None, 90.0) for m in pub)
    dr = [round(m["t"]) for m in after if m["mode"] != AIDED]
    assert len(dr) <= 2 and all(25 <= t <= 28 for t in dr), dr  # only the glitch's steps
    a_device = next(f.device for f in fixes if f.track_deg == 90.0)
    assert aiding.device == a_device and aiding.fixes_ignored > 0
    assert aiding.courses_rejected == 1 and aiding.realignments == 0


# -- GPS -> hdrd: the daemon -------------------------------------------------------------------------


class Udp:
    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = f"127.0.0.1:{self.sock.getsockname()[1]}"

    def datagrams(self, until: Callable[[list[bytes]], bool], what: str) -> list[bytes]:
        out: list[bytes] = []
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.05, deadline - time.monotonic()))
            try:
                out.append(self.sock.recvfrom(65536)[0])
            except TimeoutError:
                break
            if until(out):
                return out
        raise AssertionError(
            f"{what}: condition not met after {len(out)} datagrams; last {out[-3:]}"
        )

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def udp() -> Iterator[Callable[[], Udp]]:
    made: list[Udp] = []

    def make() -> Udp:
        u = Udp()
        made.append(u)
        return u

    try:
        yield make
    finally:
        for u in made:
            u.close()


def hdrd_run(procs: Callable[..., Proc], *args: str) -> Proc:
    env = dict(os.environ)
    for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC"):
        env.pop(k, None)
    env["STATE_DIRECTORY"] = "/nonexistent-hdrd-state"
    return procs([sys.executable, "-m", "hdrd", "run", "--log-format", "json", *args], env=env)


def straight_gyro(seconds: float, bias: float) -> DriveLog:
    hz = 10.0
    t = np.arange(int(seconds * hz)) / hz
    rng = np.random.default_rng(5)
    return DriveLog(t=t, omega=bias + rng.normal(0, 0.05, len(t)), omega_truth=np.zeros_like(t))


@pytest.mark.slow
def test_hdrd_run_aided_by_gpsd_through_an_outage(need_gpsfake, procs, fake_gyro, udp, tmp_path):
    """``hdrd run --gpsd``: a straight drive on course 250 deg, GPS lost for 12 s. The
    messages say aided -> dead-reckoning -> aided, the heading is the GPS course, holds
    through the outage, and $HNTHS says A / E."""
    port = free_port()
    js, nm = udp(), udp()
    g = fake_gyro(straight_gyro(200.0, 0.3), speedup=5.0)
    d = hdrd_run(
        procs,
        "--clock-rate",
        "5.0",
        "--port",
        g.path,
        "--bias",
        "0.3",
        "--gpsd",
        f"127.0.0.1:{port}",
        "--udp",
        js.addr,
        "--nmea-udp",
        nm.addr,
        "--nmea-ths",
    )
    g.start()
    # 5x real time, as the gyro: one GPS second per 0.2 s (two sentences, 0.1 s apart)
    gps: list[float | None] = [250.0] * 25 + [None] * 12 + [250.0] * 40
    fake = run_gpsfake(procs, tmp_path, nmea_log(gps), port, cycle=0.1)

    def seen_back(dgs: list[bytes]) -> bool:
        modes = [json.loads(x).get("mode") for x in dgs]
        runs = [a for a, b in itertools.zip_longest(modes, modes[1:]) if a != b]
        return (
            any(runs[i : i + 3] == [AIDED, DEAD_RECKONING, AIDED] for i in range(len(runs)))
            and modes[-5:] == [AIDED] * 5
        )

    try:
        msgs = [json.loads(x) for x in js.datagrams(seen_back, "JSON messages")]
    except AssertionError as e:
        raise AssertionError(f"{e}\nhdrd: {d.stderr()}\ngpsfake: {fake.stderr()}") from None
    sentences = nm.datagrams(lambda dgs: len(dgs) >= 3 * len(msgs), "NMEA")
    rc = d.stop()
    assert rc == 0, d.stderr()
    aided = [m for m in msgs if m["mode"] == AIDED]
    dr_after = [m for m in msgs[msgs.index(aided[0]) :] if m["mode"] == DEAD_RECKONING]
    assert aided and dr_after
    for m in aided:
        assert abs(wrap180(m["heading"] - 250.0)) < 1.0 and m["gps_course"] == 250.0
        assert m["gps_speed"] == pytest.approx(15.0, abs=0.2) and "heading_offset" in m
    for m in dr_after:  # straight: the heading holds, carried by HDR
        assert abs(wrap180(m["heading"] - 250.0)) < 1.0 and "gps_course" not in m
    # every message keeps the documented keys
    assert all(
        {"class", "v", "t", "step", "omega", "yaw", "heading", "bias", "status"} <= set(m)
        for m in msgs
    )
    # $HNTHS: A while aided, E in dead reckoning, same heading as the JSON message
    ths = [parse_nmea(s) for s in sentences if b"THS" in s]
    modes = {f[1] for _, f in ths}
    assert modes == {"A", "E"}
    by_heading = {(f[0], f[1]) for _, f in ths}
    for m in aided[:5] + dr_after[:5]:
        assert (f"{m['heading']:.2f}", "A" if m["mode"] == AIDED else "E") in by_heading
    log = [json.loads(x) for x in d.stderr().splitlines() if x.startswith("{")]
    assert any(e.get("event") == "gpsd_connected" for e in log)
    assert [e["mode"] for e in log if e.get("event") == "gps_mode"][-3:] == [
        AIDED,
        DEAD_RECKONING,
        AIDED,
    ]


# -- hdrd -> gpsd: NMEA over udp:// -------------------------------------------------------------------


def start_gpsd_udp(procs: Callable[..., Proc]) -> tuple[Proc, int, int]:
    """gpsd in the foreground on a free port, reading NMEA datagrams from a free UDP port."""
    port, uport = free_port(), free_port(socket.SOCK_DGRAM)
    gpsd = procs(
        [shutil.which("gpsd") or "gpsd", "-N", "-n", "-S", str(port), f"udp://127.0.0.1:{uport}"]
    )
    return gpsd, port, uport


@dataclass(frozen=True)
class Attitude:
    """gpsd's ATT report: its heading (compass deg) and the device it came from."""

    heading: float | None
    device: str | None


class AttWatch:
    """gpsd's ATT reports, read from its JSON here (hdrd's client has no use for them and
    does not parse them)."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT)
        self.sock.sendall(WATCH_COMMAND)
        self.sock.setblocking(False)
        self.buf = b""
        self.classes: set[str] = set()

    def poll_reports(self) -> list[Attitude]:
        try:
            while chunk := self.sock.recv(65536):
                self.buf += chunk
        except BlockingIOError:
            pass
        *lines, self.buf = self.buf.split(b"\n")
        out = []
        for line in lines:
            obj = json.loads(line)
            self.classes.add(obj["class"])
            if obj["class"] == "ATT":
                out.append(Attitude(obj.get("heading"), obj.get("device")))
        return out

    def close(self) -> None:
        self.sock.close()


def watch(port: int, proc: Proc) -> AttWatch:
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        try:
            c = AttWatch(port)
            break
        except ConnectionRefusedError:
            if proc.p.poll() is not None:
                raise AssertionError(f"gpsd exited: {proc.stderr()}") from None
            time.sleep(0.02)
    else:
        raise AssertionError(f"gpsd did not listen: {proc.stderr()}")
    while time.monotonic() < deadline:
        c.poll_reports()
        if "DEVICES" in c.classes:  # answered our WATCH: gpsd reads the UDP port now
            return c
        if proc.p.poll() is not None:
            break
        time.sleep(0.02)
    c.close()
    raise AssertionError(f"gpsd did not answer: {proc.stderr()}")


def test_gpsd_reports_hdrd_heading_as_att_from_hc_but_drops_hn(need_gpsd, procs):
    gpsd, port, uport = start_gpsd_udp(procs)
    c = watch(port, gpsd)
    hn = UdpNmeaPublisher([("127.0.0.1", uport)], ths=True)  # the default talker, HN
    hc = UdpNmeaPublisher([("127.0.0.1", uport)], ths=True, talker="HC")
    try:
        msg = {"class": "HDR", "v": 1, "omega": 1.5, "status": "ok", "mode": AIDED}
        for k in range(5):
            hn.on_message(msg | {"heading": 11.0 + k})
        atts: list[Attitude] = []
        k = 0
        deadline = time.monotonic() + WAIT
        while len(atts) < 5 and time.monotonic() < deadline:
            hc.on_message(msg | {"heading": 222.25 + k})  # datagrams are read in order
            k += 1
            time.sleep(0.05)
            atts += c.poll_reports()
        assert [d.errors for d in hn.stats() + hc.stats()] == [0, 0]
    finally:
        c.close()
        hn.stop()
        hc.stop()
    assert len(atts) >= 5, f"no ATT from gpsd for $HCHDT: {gpsd.stderr()}"
    headings = [a.heading for a in atts]
    hn_seen = [h for h in headings if h is not None and h < 100.0]
    assert not hn_seen, (
        f"this gpsd reports $HNHDT ({hn_seen}): update docs/protocol.md ('NMEA 0183 and gpsd') "
        "and output.nmea_talker"
    )
    assert all(h is not None and 222.25 <= h < 222.25 + k for h in headings), headings
    assert all(a.device == f"udp://127.0.0.1:{uport}" for a in atts)
    assert all(
        h == pytest.approx(round(h - 0.25) + 0.25, abs=1e-6) for h in headings if h is not None
    )


@pytest.mark.slow
def test_gpsd_reports_hdrd_run_heading_as_att(need_gpsd, procs, fake_gyro, udp, tmp_path):
    """A real ``hdrd run`` with ``output.nmea_talker: II`` (what docs/protocol.md says to set
    for gpsd) turning left at 3 deg/s: gpsd's ATT headings are the published headings (HDT,
    2 decimals)."""
    gpsd, port, uport = start_gpsd_udp(procs)
    c = watch(port, gpsd)
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("output:\n  nmea_talker: II\n")
    js = udp()
    hz = 10.0
    t = np.arange(int(120 * hz)) / hz
    g = fake_gyro(
        DriveLog(t=t, omega=np.full(t.shape[0], 3.3), omega_truth=np.full(t.shape[0], 3.0)),
        speedup=10.0,
    )
    d = hdrd_run(
        procs,
        "--clock-rate",
        "10.0",
        "--config",
        str(cfg),
        "--port",
        g.path,
        "--bias",
        "0.3",
        "--heading0",
        "10",
        "--udp",
        js.addr,
        "--nmea-udp",
        f"127.0.0.1:{uport}",
        "--nmea-ths",
    )
    g.start()
    atts: list[Attitude] = []
    try:
        deadline = time.monotonic() + WAIT
        while len(atts) < 10 and time.monotonic() < deadline:
            atts += c.poll_reports()
            time.sleep(0.02)
        msgs = [json.loads(x) for x in js.datagrams(lambda dgs: len(dgs) >= 40, "JSON messages")]
    finally:
        c.close()
        rc = d.stop()
    assert rc == 0, d.stderr()
    assert len(atts) >= 10, (
        f"gpsd reported {len(atts)} ATT; gpsd: {gpsd.stderr()}; hdrd: {d.stderr()}"
    )
    published = {round(m["heading"], 2) for m in msgs}
    got = [round(a.heading, 2) for a in atts if a.heading is not None]
    assert set(got) <= published, (got, sorted(published)[:5])
    # the heading turns left (compass down) through north: 10 -> 0 -> 357 ...
    assert got[0] > got[-1] or got[-1] > 300.0


def test_ths_mode_follows_the_aiding_mode_and_the_talker_is_configurable():
    from hdrd.io.net.formats import nmea_sentences

    base = {"class": "HDR", "v": 1, "omega": -0.5, "heading": 359.996, "status": "ok"}

    def ths(msg: dict[str, Any], talker: str = "HN") -> tuple[str, list[str]]:
        (s,) = [x for x in nmea_sentences(msg, ths=True, talker=talker) if b"THS" in x]
        return parse_nmea(s)

    assert ths(base | {"mode": AIDED}) == ("HNTHS", ["0.00", "A"])
    assert ths(base | {"mode": DEAD_RECKONING}) == ("HNTHS", ["0.00", "E"])
    assert ths(base) == ("HNTHS", ["0.00", "E"])  # no GPS aiding configured
    assert ths(base | {"mode": AIDED, "status": "stale"})[1][1] == "V"
    kinds = [
        parse_nmea(s)[0] for s in nmea_sentences(base | {"mode": AIDED}, ths=True, talker="HC")
    ]
    assert kinds == ["HCHDT", "HCROT", "HCTHS"]


# -- what gpsd 3.22 does with a held heading, and which talkers it reads -------------------------


def _atts_for(c: AttWatch, pub: UdpNmeaPublisher, msgs: list[dict[str, Any]]) -> list[Attitude]:
    """Send *msgs* (each once), then a live marker message until gpsd reports it; the ATT
    reports seen before the marker are what *msgs* produced (datagrams are read in order)."""
    for m in msgs:
        pub.on_message(m)
    marker = {"class": "HDR", "v": 1, "omega": 0.0, "status": "ok", "heading": 300.5}
    atts: list[Attitude] = []
    deadline = time.monotonic() + WAIT
    while not any(a.heading == 300.5 for a in atts) and time.monotonic() < deadline:
        pub.on_message(marker)
        time.sleep(0.05)
        atts += c.poll_reports()
    assert any(a.heading == 300.5 for a in atts), "gpsd never reported the marker heading"
    return atts[: next(i for i, a in enumerate(atts) if a.heading == 300.5)]


def test_gpsd_takes_no_held_heading_for_a_fresh_one(need_gpsd, procs):
    """While the gyro is unplugged the messages hold the last heading (status stale). gpsd
    used to report each as a fresh ATT heading ($--HDT has no validity field); now hdrd
    sends no HDT then, and THS says V."""
    from tests.test_pipeline import make_frames, run_live

    gpsd, port, uport = start_gpsd_udp(procs)
    c = watch(port, gpsd)
    pub = UdpNmeaPublisher([("127.0.0.1", uport)], ths=True, talker="II")
    p = Pipeline(PipelineConfig(heading0_deg=123.0, setup=MethodSetup(bias=given_bias(0.0))))
    assert len(run_live(p, make_frames(np.zeros(30)))) == 3  # three real steps, then silence
    stale = [p.stale_message(None, silent_s=3.0 + k) for k in range(5)]
    assert all(m["status"] == "stale" and m["heading"] == 123.0 for m in stale)
    try:
        held = _atts_for(c, pub, stale)
    finally:
        c.close()
        pub.stop()
    assert [a.heading for a in held] == [], f"gpsd took a held heading for a fresh one: {held}"


@pytest.mark.parametrize("talker", ["II", "IN", "HC"])
def test_gpsd_reads_the_talkers_the_docs_offer(need_gpsd, procs, talker):
    """docs/protocol.md offers these talkers for gpsd; gpsd 3.22 must read $--HDT from each."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    assert f"`{talker}`" in doc
    gpsd, port, uport = start_gpsd_udp(procs)
    c = watch(port, gpsd)
    pub = UdpNmeaPublisher([("127.0.0.1", uport)], talker=talker)
    try:
        atts = _atts_for(c, pub, [{"class": "HDR", "v": 1, "status": "ok", "heading": 42.25}])
    finally:
        c.close()
        pub.stop()
    assert [a.heading for a in atts] == [42.25]


# -- GPS -> hdrd: courses faster than the step --------------------------------------------------


def rmc(t_s: float, course: float, speed_mps: float = 15.0) -> bytes:
    """One $GPRMC at t_s seconds after 12:00:00 (hundredths), a fix on ``course``."""
    t = 12 * 3600.0 + t_s
    hms = f"{int(t // 3600):02d}{int(t % 3600 // 60):02d}{t % 60:05.2f}"
    body = (
        f"GPRMC,{hms},A,4806.0000,N,01130.0000,E,{speed_mps / KNOT_MPS:.3f},{course:.2f},211125,,,A"
    )
    return sentence(body).encode()


@pytest.mark.slow
def test_hdrd_run_holds_its_heading_when_gpsd_alternates_two_courses(
    need_gpsd, procs, fake_gyro, udp
):
    """A real gpsd reads a receiver that reports 100 times a second, alternating courses 90
    and 270 (after 2 s of 90 alone); a real ``hdrd run --gpsd`` on a still gyro. The fixes of
    one step contradict one another: no step takes a course and the heading never flips
    (it used to realign to 270 and back, twice in 17 s, published as aided)."""
    gpsd, port, uport = start_gpsd_udp(procs)
    watch(port, gpsd).close()  # gpsd answers: it reads its UDP port
    js = udp()
    g = fake_gyro(straight_gyro(400.0, 0.0), speedup=5.0)
    d = hdrd_run(
        procs, "--clock-rate", "5.0", "--port", g.path, "--bias", "0", "--gpsd",
        f"127.0.0.1:{port}", "--udp", js.addr,
    )  # fmt: skip
    g.start()
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        t0 = time.monotonic()
        k = 0
        while (now := time.monotonic() - t0) < 14.0:  # 70 steps of the gyro at 5x
            course = 90.0 if now < 2.0 or k % 2 == 0 else 270.0
            out.sendto(rmc(k * 0.01, course), ("127.0.0.1", uport))
            k += 1
            time.sleep(0.01)
        msgs = [json.loads(x) for x in js.datagrams(lambda dgs: len(dgs) >= 60, "steps")]
    finally:
        out.close()
        rc = d.stop()
    assert rc == 0, d.stderr()
    aligned = [m for m in msgs if "heading_offset" in m]
    assert aligned, f"never aligned: {d.stderr()}"
    assert all(abs(wrap180(m["heading"] - 90.0)) < 0.5 for m in aligned), [
        m["heading"] for m in aligned
    ]
    log = [json.loads(x) for x in d.stderr().splitlines() if x.startswith("{")]
    assert not [e for e in log if e.get("event") == "gps_realigned"]
    said = [e for e in log if e.get("event") == "gps_courses_disagree"]
    assert said and said[0]["level"] == "warning"
    assert msgs[-1]["mode"] == DEAD_RECKONING  # the alternation is no course at all


@pytest.mark.slow
def test_hdrd_run_refuses_a_speed_no_car_has(procs, fake_gyro, udp):
    """A gpsd peer whose TPVs say 1e9 m/s on course 90: not a fix. No step is aided, no
    ``gps_speed`` is published (it was, 1e9, aided), the log says why once."""
    from tests.test_gpsd import Peer

    peer = Peer()
    js = udp()
    g = fake_gyro(straight_gyro(400.0, 0.0), speedup=5.0)
    try:
        d = hdrd_run(
            procs, "--clock-rate", "5.0", "--port", g.path, "--bias", "0", "--gpsd",
            f"127.0.0.1:{peer.port}", "--udp", js.addr,
        )  # fmt: skip
        g.start()
        assert b"WATCH" in peer.accept()
        peer.send('{"class":"VERSION","release":"3.22","proto_major":3,"proto_minor":14}\n')
        t0 = time.monotonic()
        while time.monotonic() - t0 < 4.0:  # 20 steps of the gyro at 5x
            peer.send('{"class":"TPV","device":"/dev/ttyUSB0","mode":3,"track":90.0,"speed":1e9}\n')
            time.sleep(0.05)
        msgs = [json.loads(x) for x in js.datagrams(lambda dgs: len(dgs) >= 15, "steps")]
        rc = d.stop()
    finally:
        peer.close()
    assert rc == 0, d.stderr()
    assert all("gps_speed" not in m and m["mode"] == DEAD_RECKONING for m in msgs), msgs[-1]
    log = [json.loads(x) for x in d.stderr().splitlines() if x.startswith("{")]
    refused = [e for e in log if e.get("event") == "gps_fix_refused"]
    assert len(refused) == 1 and refused[0]["speed_mps"] == 1e9, refused
