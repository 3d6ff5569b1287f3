# ruff: noqa: F811 - the fixtures hdrd and receivers come from test_rel_daemon by import
"""``hdrd run`` beside inputs and outputs that misbehave: whatever answers on the gpsd address
(lines no parser can use, negative speeds, a flood), a stdout reader that stalls, a device
that is not there; and the systemd watchdog fed only while the loop makes progress.

Real components: a daemon process reading a fake gyro on a real pty (or its simulated gyro),
a TCP listener speaking as gpsd would (the real gpsd never sends such lines; tests with the
real gpsd are in test_gpsd_nmea.py), real UDP receivers, a real pipe that nobody reads, a
real NOTIFY_SOCKET. No timings are asserted: every wait is a generous upper bound that only a
hung or starved daemon reaches. The watchdog rule itself, call by call: test_sdnotify.py.
"""

from __future__ import annotations

import fcntl
import os
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from hdrd.io.net.formats import parse_nmea
from tests.test_rel_daemon import (  # noqa: F401 - hdrd and receivers are fixtures
    WAIT,
    Msgs,
    Receiver,
    constant_turn,
    fast_config,
    hdrd,
    receivers,
    run_args,
    run_on_link,
    steps_of,
    wait_port_open,
)

F_SETPIPE_SZ = 1031


class GpsdPeer:
    """A TCP listener on 127.0.0.1 that plays gpsd: accepts one client (in a thread) and
    sends what the test says, or floods."""

    def __init__(self) -> None:
        self.srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen(4)
        self.port = self.srv.getsockname()[1]
        self.conn: socket.socket | None = None
        self.connected = threading.Event()
        self.stop = threading.Event()
        self.sent = 0
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        self.srv.settimeout(WAIT)
        try:
            self.conn, _ = self.srv.accept()
        except OSError:
            return
        self.conn.settimeout(WAIT)
        self.connected.set()

    def send(self, data: bytes) -> None:
        assert self.connected.wait(WAIT), "hdrd never connected to gpsd"
        assert self.conn is not None
        self.conn.sendall(data)

    def flood(self, line: bytes) -> threading.Thread:
        """Send *line* over and over, as fast as the client takes it, until stop is set."""
        chunk = line * (65536 // len(line))

        def run() -> None:
            try:
                while not self.stop.is_set():
                    self.send(chunk)
                    self.sent += len(chunk)
            except OSError:
                pass

        t = threading.Thread(target=run, daemon=True)
        t.start()
        return t

    def close(self) -> None:
        self.stop.set()
        if self.conn is not None:
            self.conn.close()
        self.srv.close()


@pytest.fixture
def gpsd_peer() -> Iterator[GpsdPeer]:
    p = GpsdPeer()
    try:
        yield p
    finally:
        p.close()


def tpv(mode: int = 3, **kv: object) -> bytes:
    body = ",".join(f'"{k}":{v}' for k, v in kv.items())
    return f'{{"class":"TPV","mode":{mode}{"," + body if body else ""}}}\n'.encode()


@pytest.mark.slow
def test_lines_no_parser_can_use_do_not_stop_run_gpsd(
    hdrd, receivers, fake_gyro, gpsd_peer, tmp_path
):
    """Each of these lines used to end ``hdrd run --gpsd`` with a traceback; a negative
    speed was published as is. Now the daemon carries on, and the good fix after them is
    used."""
    g = fake_gyro(constant_turn(minutes=3), speedup=4)
    rx = receivers()
    d = hdrd(
        *run_args("--clock-rate", "4", "--port", g.path, "--bias", "0", "--udp", rx.addr),
        "--gpsd",
        f"127.0.0.1:{gpsd_peer.port}",
    )
    wait_port_open(d, g.path)
    g.start()
    rx.wait(lambda ms: len(ms) >= 2, what="first steps")
    huge, beyond = "9" * 5000, "1" + "0" * 400
    gpsd_peer.send(
        tpv(speed=-20.0, track=90.0) * 3
        + tpv(speed=huge)
        + tpv(speed=beyond, track=90.0)
        + tpv(speed=f"-{beyond}")
        + b'{"class":"TPV","mode":3,"time":"0000-01-01T00:00:00Z","speed":1}\n'
        + b'{"class":"SKY","satellites":[{"PRN":'
        + huge.encode()
        + b"}]}\n"
        + b"[" * 60000
        + b"\n"
    )
    for _ in range(50):  # then a real moving fix, 5 Hz, while we watch
        gpsd_peer.send(tpv(speed=15.0, track=90.0))
        if any(m.get("gps_speed") == 15.0 for m in rx.snapshot()):
            break
        assert d.alive, f"hdrd died: {d.other[-5:]}"
        time.sleep(0.2)
    ms = rx.wait(
        lambda ms: any(m.get("gps_speed") == 15.0 for m in ms), what="a step with the good fix"
    )
    assert d.alive and d.stop() == 0 and not d.traceback, d.other[-10:]
    assert all(m.get("gps_speed", 0.0) >= 0.0 for m in ms)  # no negative speed published
    bad = d.named("gpsd_bad_lines")  # counted and said (at most every 10 s)
    assert bad and bad[0]["total"] >= 1 and "too many digits" in bad[0]["last"]


@pytest.mark.slow
def test_a_flooding_gpsd_does_not_hold_up_the_steps(
    hdrd, receivers, fake_gyro, gpsd_peer, tmp_path
):
    """A peer sending short lines as fast as TCP takes them: the steps keep coming (one in
    20 s used to), and the watchdog, fed by published steps, keeps being fed."""
    g = fake_gyro(constant_turn(minutes=3), speedup=4)
    rx = receivers()
    notify = receivers(tmp_path / "notify.sock")
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "2000000"}
    d = hdrd(
        *run_args("--clock-rate", "4", "--port", g.path, "--bias", "0", "--udp", rx.addr),
        "--gpsd",
        f"127.0.0.1:{gpsd_peer.port}",
        env=env,
    )
    wait_port_open(d, g.path)
    flooder = gpsd_peer.flood(tpv(mode=1))
    assert gpsd_peer.connected.wait(WAIT)
    g.start()
    # 40 frames/s: 20 steps are 5 s of device time; WAIT is six times that
    ms = rx.wait(lambda ms: len(steps_of(ms)) >= 20, what="20 steps while gpsd floods")
    pings = notify.wait(
        lambda xs: xs.count("WATCHDOG=1") >= 2, what="the watchdog fed during the flood"
    )
    assert gpsd_peer.sent > 10 * 65536  # it did flood (and hdrd read it)
    assert [m["step"] for m in steps_of(ms)][:20] == list(range(20))
    gpsd_peer.stop.set()
    flooder.join(WAIT)
    assert d.alive and d.stop() == 0 and not d.traceback
    assert "READY=1" in pings


@pytest.mark.slow
def test_a_stalled_stdout_reader_holds_up_nothing_and_sigterm_is_honoured(hdrd, receivers):
    """stdout is a one-page pipe that nobody reads. The UDP output goes on at full rate,
    stdout lines are dropped and counted, and SIGTERM ends the daemon (it used to block in
    write(2): no more UDP, and SIGTERM waited on the reader)."""
    r, w = os.pipe()
    fcntl.fcntl(w, F_SETPIPE_SZ, 4096)
    rx = receivers()
    try:
        d = hdrd(
            *run_args("--simulate", "--drive", "standstill", "--speedup", "200"),
            "--bias",
            "0.2",
            "--stdout",
            "--udp",
            rx.addr,
            stdout=w,
        )
        os.close(w)
        w = -1
        # 1000 steps are 330 KB of JSON: the pipe (4 KiB) and the queue (256 KiB) overflow
        rx.wait(lambda ms: len(ms) >= 1000, what="1000 steps over UDP with stdout stalled")
        d.wait_event("output_dropped")
        assert d.alive
        assert d.stop() == 0 and not d.traceback, d.other[-10:]
        (stop,) = d.named("stop")
        assert stop["output_dropped"] > 0 and stop["steps"] >= 1000
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


@pytest.mark.slow
def test_the_watchdog_is_fed_while_the_device_is_away(hdrd, receivers, tmp_path):
    """No device at all: nothing to step on, yet the daemon is healthy (it waits and
    reports stale): the source's idle turns feed the watchdog, so systemd leaves it be."""
    notify = receivers(tmp_path / "notify.sock")
    rx = receivers()
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "400000"}
    d = hdrd(
        *run_args("--port", str(tmp_path / "no-such-tty"), "--bias", "0", "--udp", rx.addr),
        env=env,
    )
    notify.wait(lambda xs: xs.count("WATCHDOG=1") >= 5, what="5 watchdog pings, no device")
    rx.wait(lambda ms: len(ms) >= 1 and ms[-1]["status"] == "stale", what="stale reports")
    assert d.stop() == 0 and not d.traceback


@pytest.mark.slow
def test_no_hdt_while_the_gyro_is_unplugged(hdrd, receivers, fake_gyro, tmp_path):
    """A pulled cable: the JSON stale reports hold the heading; the NMEA output says so with
    THS V and no HDT (a receiver takes every HDT for a fresh heading), and HDT is back
    with the steps."""
    link = tmp_path / "gyro"
    cfg = fast_config(tmp_path)
    g = fake_gyro(constant_turn(minutes=5), speedup=4, link=link)
    rx = receivers()
    ns = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ns.bind(("127.0.0.1", 0))
    nm = Receiver(ns, parse_nmea)
    try:
        nmea = f"127.0.0.1:{ns.getsockname()[1]}"
        d = run_on_link(hdrd, g, link, cfg, rx, "--nmea-udp", nmea, "--nmea-ths")
        rx.wait(lambda ms: len(steps_of(ms)) >= 4, what="4 steps")
        g.pull(3.0)

        def resumed(ms: Msgs) -> bool:
            gaps = [i for i, m in enumerate(ms) if "gap_s" in m]
            return bool(gaps) and len(ms) > gaps[0] + 3

        rx.wait(resumed, what="steps after the cable is back")
        assert d.stop() == 0 and not d.traceback
        ms = rx.snapshot()
        sentences = nm.wait(
            lambda xs: sum(k.endswith("THS") for k, _ in xs) >= len(ms), what="THS per message"
        )
    finally:
        nm.close()
    groups: list[dict[str, list[str]]] = [{}]
    for kind, fields in sentences:  # each message: [HDT] ROT THS, in order
        groups[-1][kind[2:]] = fields
        if kind.endswith("THS"):
            groups.append({})
    stale = [(m, grp) for m, grp in zip(ms, groups) if m["status"] == "stale"]
    live = [(m, grp) for m, grp in zip(ms, groups) if m["status"] != "stale"]
    assert stale and live
    for m, grp in stale:
        assert "HDT" not in grp and grp["ROT"] == ["", "V"]
        assert grp["THS"] == [f"{m['heading']:.2f}", "V"]
    for m, grp in live:
        assert grp["HDT"] == [f"{m['heading']:.2f}", "T"] and grp["THS"][1] == "E"
        assert grp["ROT"][1] == "A"
