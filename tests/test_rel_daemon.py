"""`hdrd run` as a process under trouble it cannot prevent.

A real daemon process reads a fake gyro on a real pty (through a symlink that disappears with
it on a cable pull) and publishes over real UDP; a NOTIFY_SOCKET listens where systemd would.
Pulled cables (5 s, repeatedly, and a long pull: 20 s, or HDRD_TEST_LONG_PULL_S), a device that
sends nothing, dead UDP peers, a `hdrd tail` that comes and goes, a reader that closes stdout,
signals during calibration, a reconnect and a burst of bad frames, SIGHUP with broken
configurations, and a restart that must resume with the saved bias.

Already in tests/test_daemon.py and not repeated: one short unplug/replug, SIGHUP with an
out-of-range value, one dead peer, SIGTERM while publishing, `| head`, exit 78, calibrate.

No timings are asserted; every wait is a generous upper bound that only a hung daemon
reaches. Counts are exact where the construction makes them known: when the fake gyro
resumes after a pull it waits until the daemon has logged ``device_back`` (its serial port
reopened and flushed), so every frame the fake delivers reaches the daemon.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdrd.core.calibrate import BiasRecord
from hdrd.core.sensor import SensorModel
from hdrd.io.files.biasfile import load_bias, save_bias
from hdrd.io.files.drivelog import DriveLog
from hdrd.io.wire.codec import FRAME_DTYPE
from hdrd.sim.profiles import builtin_profile

WAIT = 30.0  # upper bound for anything to happen; only a hung daemon reaches it
# The long cable pull, wall s. 20 s already keeps the reconnect back-off at its 2 s ceiling
# for most of the outage, with about 20 stale reports and 40 watchdog pings to count;
# HDRD_TEST_LONG_PULL_S=60 makes it the full minute (or longer, for a soak by hand).
LONG_PULL_S = float(os.environ.get("HDRD_TEST_LONG_PULL_S", "20"))

Msgs = list[dict[str, Any]]


# --------------------------------------------------------------------------- harness


class Receiver(threading.Thread):
    """Datagrams arriving on a socket, kept in order with their arrival time (monotonic)."""

    def __init__(self, sock: socket.socket, decode: Callable[[bytes], Any]) -> None:
        super().__init__(daemon=True)
        self.sock = sock
        self.sock.settimeout(0.1)
        self.decode = decode
        self.items: list[Any] = []
        self.times: list[float] = []
        self.cond = threading.Condition()
        self.done = threading.Event()
        self.addr = ""
        """HOST:PORT of a UDP receiver (what ``--udp`` takes)."""
        self.start()

    def run(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                if self.done.is_set():
                    return
                continue
            except OSError:
                return
            with self.cond:
                self.items.append(self.decode(data))
                self.times.append(time.monotonic())
                self.cond.notify_all()

    def wait(
        self, pred: Callable[[list[Any]], bool], timeout: float = WAIT, what: str = ""
    ) -> list[Any]:
        with self.cond:
            if not self.cond.wait_for(lambda: pred(self.items), timeout):
                raise AssertionError(
                    f"not seen within {timeout} s: {what}; {len(self.items)} items, last {self.items[-3:]}"
                )
            return list(self.items)

    def snapshot(self) -> list[Any]:
        with self.cond:
            return list(self.items)

    def close(self) -> None:
        self.done.set()
        self.join(timeout=5)
        self.sock.close()


def udp_receiver() -> Receiver:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    s.bind(("127.0.0.1", 0))
    r = Receiver(s, json.loads)
    r.addr = f"127.0.0.1:{s.getsockname()[1]}"
    return r


def notify_receiver(path: Path) -> Receiver:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    return Receiver(s, lambda b: b.decode())


class Proc:
    """`python -m hdrd <command> ...` with its JSON log read live from stderr."""

    def __init__(
        self,
        argv: list[str],
        env: dict[str, str],
        stdout: Any = subprocess.DEVNULL,
        prefix: tuple[str, ...] = (),
    ) -> None:
        self.proc = subprocess.Popen(
            [*prefix, sys.executable, "-m", "hdrd", *argv],
            stdout=stdout,
            stderr=subprocess.PIPE,
            env=env,
        )
        self.events: list[dict[str, Any]] = []
        self.other: list[str] = []
        self.cond = threading.Condition()
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for raw in self.proc.stderr:
            line = raw.decode("utf-8", "replace").rstrip("\n")
            with self.cond:
                try:
                    self.events.append(json.loads(line))
                except json.JSONDecodeError:
                    self.other.append(line)
                self.cond.notify_all()

    def count(self, name: str) -> int:
        with self.cond:
            return sum(1 for e in self.events if e.get("event") == name)

    def wait_event(self, name: str, n: int = 1, timeout: float = WAIT) -> None:
        with self.cond:
            ok = self.cond.wait_for(
                lambda: sum(1 for e in self.events if e.get("event") == name) >= n, timeout
            )
        assert ok, (
            f"no {n} x {name!r} within {timeout} s; events {[e.get('event') for e in self.events]}, other {self.other[-5:]}"
        )

    def named(self, name: str) -> list[dict[str, Any]]:
        with self.cond:
            return [e for e in self.events if e.get("event") == name]

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        rc = self.proc.wait(timeout=WAIT)
        self._close_log()
        return rc

    def _close_log(self) -> None:
        """The log is read to its end (the process has exited): close our end of the pipe."""
        self._t.join(timeout=10)
        if self.proc.stderr is not None and not self._t.is_alive():
            self.proc.stderr.close()

    @property
    def traceback(self) -> bool:
        return any("Traceback" in line for line in self.other)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=WAIT)
        self._close_log()
        if self.proc.stdout is not None:  # stdout=PIPE: the test has read what it wanted
            self.proc.stdout.close()


@pytest.fixture
def hdrd(tmp_path: Path) -> Iterator[Callable[..., Proc]]:
    """Factory of hdrd processes, all killed after the test. STATE_DIRECTORY is an empty
    directory of the test's (no bias file) unless the test sets it; ``prefix`` runs the
    command under another (``unshare ...``)."""
    made: list[Proc] = []
    state = tmp_path / "empty-state"
    state.mkdir()

    def make(
        *argv: str,
        env: dict[str, str] | None = None,
        stdout: Any = subprocess.DEVNULL,
        prefix: tuple[str, ...] = (),
    ) -> Proc:
        e = dict(os.environ)
        for k in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
            e.pop(k, None)
        e["STATE_DIRECTORY"] = str(state)
        e.update(env or {})
        p = Proc(list(argv), e, stdout, prefix)
        made.append(p)
        return p

    yield make
    for p in made:
        p.kill()


@pytest.fixture
def receivers() -> Iterator[Callable[..., Receiver]]:
    made: list[Receiver] = []

    def make(notify: Path | None = None) -> Receiver:
        r = udp_receiver() if notify is None else notify_receiver(notify)
        made.append(r)
        return r

    yield make
    for r in made:
        r.close()


def run_args(*extra: str) -> list[str]:
    return ["run", "--log-format", "json", *extra]


def wait_port_open(p: Proc, path: str | Path) -> None:
    """Until the daemon holds the tty open (so a paced fake gyro loses no frame to nobody)."""
    target = os.path.realpath(path)
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        assert p.alive, f"daemon exited: {p.other[-5:]}"
        fds = Path(f"/proc/{p.proc.pid}/fd")
        try:
            if any(os.path.realpath(f) == target for f in fds.iterdir()):
                return
        except (FileNotFoundError, PermissionError):
            pass
        time.sleep(0.02)
    raise AssertionError(f"the daemon never opened {path}")


def fast_config(tmp_path: Path, **extra: str) -> Path:
    """Stale after 0.5 s, reconnect backoff 0.1 s doubling up to ``max`` (default 0.5 s)."""
    cfg = tmp_path / "hdrd.yaml"
    body = f"device:\n  stale_after_s: 0.5\n  reconnect_min_s: 0.1\n  reconnect_max_s: {extra.pop('reconnect_max_s', '0.5')}\n"
    for section, text in extra.items():
        body += f"{section}:\n{text}"
    cfg.write_text(body)
    return cfg


def steps_of(ms: Msgs) -> Msgs:
    return [m for m in ms if m["status"] != "stale"]


def resume_after_device_back(g: Any, d: Proc) -> None:
    """The fake gyro resumes after a pull only once the daemon has its port back."""
    g.on_pull_end = lambda: d.wait_event("device_back", g.injected.pulls)


def run_on_link(
    hdrd: Callable[..., Proc],
    g: Any,
    link: Path,
    cfg: Path,
    rx: Receiver,
    *more: str,
    env: dict[str, str] | None = None,
) -> Proc:
    """``hdrd run`` on the fake gyro ``g`` at 4 times real time, reached through the symbolic
    link ``link`` (a cable that can be pulled), with the configuration ``cfg``, bias 0 and UDP
    to ``rx`` (and ``more`` options); the gyro starts once the daemon holds the port and
    resumes after a pull only once it has it back."""
    d = hdrd(
        *run_args(
            "--clock-rate", "4", "--config", str(cfg), "--port", str(link), "--bias", "0",
            "--udp", rx.addr, *more,
        ),
        env=env,
    )  # fmt: skip
    resume_after_device_back(g, d)
    wait_port_open(d, link)
    g.start()
    return d


def constant_turn(minutes: float = 5.0, rate_dps: float = 2.0) -> DriveLog:
    return builtin_profile(
        "constant", minutes=minutes, rate_dps=rate_dps, bias_dps=0.0, noise_dps=0.0, lead_in_s=0
    )


def check_heading_continuous(ms: Msgs, heading0: float) -> None:
    """Steps only go forward; yaw grows by about one step's 2 deg (a constant 2 deg/s CCW turn)
    from step to step, across every gap too, never jumping back to 0 nor ahead by the gap;
    stale reports hold the last step's heading."""
    steps = steps_of(ms)
    nums = [m["step"] for m in steps]
    assert nums == sorted(set(nums)), nums
    yaws = [m["yaw"] for m in steps]
    assert all(0.0 < b - a < 3.0 for a, b in itertools.pairwise(yaws)), yaws
    for m in steps:
        assert m["heading"] == pytest.approx((heading0 - m["yaw"]) % 360.0)
    last: dict[str, Any] | None = None
    for m in ms:
        if m["status"] != "stale":
            last = m
        elif last is not None:
            assert (m["step"], m["yaw"], m["heading"]) == (
                last["step"],
                last["yaw"],
                last["heading"],
            )


# --------------------------------------------------------------------------- 2. pulled cable


@pytest.mark.slow
def test_cable_pulled_for_5_s_then_repeatedly_then_sigterm_while_out(
    fake_gyro, hdrd, receivers, tmp_path
):
    link = tmp_path / "gyro"
    cfg = fast_config(tmp_path)
    notify = receivers(tmp_path / "notify.sock")
    g = fake_gyro(constant_turn(), speedup=4, link=link)
    rx = receivers()
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify.sock")}
    d = run_on_link(hdrd, g, link, cfg, rx, "--heading0", "10", env=env)
    rx.wait(lambda ms: len(steps_of(ms)) >= 6, what="6 steps")
    pulls = [5.0, 1.5, 1.5, 1.5]
    for k, seconds in enumerate(pulls, 1):
        g.pull(seconds)

        def resumed(ms: Msgs, k: int = k) -> bool:
            gaps = [i for i, m in enumerate(ms) if "gap_s" in m]
            return len(gaps) >= k and len(steps_of(ms[gaps[k - 1] :])) >= 4

        rx.wait(resumed, timeout=seconds + WAIT, what=f"steps after pull {k}")
        assert d.alive
    # 5. SIGTERM while the cable is out and the daemon is reconnecting: clean exit 0.
    g.pull(60.0)
    d.wait_event("device_lost", len(pulls) + 1)
    rx.wait(lambda ms: ms[-1]["status"] == "stale", what="stale after the last pull")
    assert d.alive
    assert d.stop() == 0 and not d.traceback
    stop = d.named("stop")[-1]
    assert stop["reconnects"] == len(pulls)
    assert d.count("device_lost") == len(pulls) + 1 and d.count("device_back") == len(pulls)
    delivered = int(g.delivered.sum())
    ms = rx.wait(
        lambda ms: sum(m.get("samples", 0) for m in ms) >= delivered,
        what="every delivered frame in a step",
    )

    steps = steps_of(ms)
    # Every delivered frame is in exactly one step; no step is made up for the time the
    # cable was out (about 38 device seconds were never sent): steps <= device seconds
    # delivered + a partial block at each end of each of the 5 connections.
    assert sum(m["samples"] for m in steps) == delivered
    assert all(1 <= m["samples"] <= 10 for m in steps)
    assert g.injected.pulled_frames / 10 > 30
    assert len(steps) <= delivered / 10 + 2 * 5
    # Each return is reported once, with the length of the gap; only stale reports between.
    gap_idx = [i for i, m in enumerate(ms) if "gap_s" in m]
    assert len(gap_idx) == len(pulls)
    gaps = [ms[i]["gap_s"] for i in gap_idx]  # device s: the time away times the rate, 4
    assert 4 * 4.5 < gaps[0] < 4 * (5.0 + WAIT)
    assert all(4 * 1.25 < x < 4 * (1.5 + WAIT) for x in gaps[1:]), gaps
    prev = 0
    for i in gap_idx:
        # While out: one run of stale reports, then the block open at the pull is closed
        # (published at the return) and the next step carries gap_s.
        stale = [j for j in range(prev, i) if ms[j]["status"] == "stale"]
        assert stale and stale == list(range(stale[0], stale[-1] + 1)) and stale[-1] < i - 1
        assert all(ms[j]["stale_s"] > 0.5 for j in stale)
        prev = i
    check_heading_continuous(ms, 10.0)
    # systemd was told: ready once, stale while out, back to normal after.
    seen = notify.wait(lambda xs: "STOPPING=1" in xs, what="STOPPING=1")
    assert seen.count("READY=1") == 1
    status = [s for s in seen if s.startswith("STATUS=")]
    first_stale = next(i for i, s in enumerate(status) if "stale" in s)
    assert any(s.startswith(("STATUS=ok", "STATUS=turning")) for s in status[first_stale:])


@pytest.mark.slow
def test_cable_pulled_for_long(fake_gyro, hdrd, receivers, tmp_path):
    """LONG_PULL_S (20 s; a minute with HDRD_TEST_LONG_PULL_S=60) without the device.
    Reconnect attempts back off up to 2 s; the watchdog keeps being fed; stale reports keep
    coming; the daemon comes back by itself and carries on."""
    link = tmp_path / "gyro"
    cfg = fast_config(tmp_path, reconnect_max_s="2.0")
    notify = receivers(tmp_path / "notify.sock")
    g = fake_gyro(constant_turn(minutes=2 + LONG_PULL_S * 4 / 60), speedup=4, link=link)
    rx = receivers()
    env = {"NOTIFY_SOCKET": str(tmp_path / "notify.sock"), "WATCHDOG_USEC": "1000000"}
    d = run_on_link(hdrd, g, link, cfg, rx, env=env)
    rx.wait(lambda ms: len(steps_of(ms)) >= 4, what="4 steps")
    g.pull(LONG_PULL_S)

    def resumed(ms: Msgs) -> bool:
        gaps = [i for i, m in enumerate(ms) if "gap_s" in m]
        return bool(gaps) and len(steps_of(ms[gaps[0] :])) >= 4

    ms = rx.wait(resumed, timeout=LONG_PULL_S + WAIT, what="steps after the long pull")
    assert d.alive
    assert d.stop() == 0 and not d.traceback
    delivered = int(g.delivered.sum())
    ms = rx.wait(
        lambda ms: sum(m.get("samples", 0) for m in ms) >= delivered,
        what="every delivered frame in a step",
    )
    k = next(i for i, m in enumerate(ms) if "gap_s" in m)
    # in device seconds: the wall clock's time away times the clock rate, 4
    assert 4 * LONG_PULL_S / 2 < ms[k]["gap_s"] < 4 * (LONG_PULL_S + WAIT)
    stale = [i for i, m in enumerate(ms[:k]) if m["status"] == "stale"]
    assert len(stale) >= LONG_PULL_S / 2  # one per T (1 s) while out
    t_out, t_back = rx.times[stale[0]], rx.times[k]
    pings = [
        t for s, t in zip(notify.items, notify.times) if s == "WATCHDOG=1" and t_out <= t <= t_back
    ]
    # every 0.5 s while out; a loop stuck reconnecting would starve it
    assert len(pings) >= LONG_PULL_S / 2
    assert sum(m["samples"] for m in steps_of(ms)) == delivered
    check_heading_continuous(ms, 0.0)
    assert d.count("device_lost") == 1 and d.count("device_back") == 1


def silent_hole_frames() -> np.ndarray:
    """10 Hz frames of a 1 deg/s turn for device seconds [0, 6), nothing for 20 s, then [26, 34)."""
    t = np.concatenate([np.arange(0, 60), np.arange(260, 340)]) * 100_000
    arr = np.zeros(t.shape[0], FRAME_DTYPE)
    arr["seq"] = np.arange(t.shape[0])
    arr["t_us"] = t
    arr["rate"] = SensorModel().to_counts(np.full(t.shape[0], 1.0))
    arr["temp"] = -32768
    return arr


@pytest.mark.slow
def test_device_that_sends_nothing(fake_gyro, hdrd, receivers, tmp_path):
    """The port stays open but no byte comes: first before any data, then for 20 device
    seconds in the middle. Stale reports (holding the last heading, or none before the
    first step), no exit, no reconnect; when data comes back, the step numbers skip the
    20 missing steps (not invented) and the first step after says gap_s = 20."""
    cfg = fast_config(tmp_path)
    g = fake_gyro(silent_hole_frames(), speedup=8)
    rx = receivers()
    d = hdrd(
        *run_args(
            "--clock-rate",
            "8",
            "--config",
            str(cfg),
            "--port",
            g.path,
            "--bias",
            "0",
            "--udp",
            rx.addr,
        )
    )
    early = rx.wait(lambda ms: len(ms) >= 2, what="stale reports before any data")
    assert all(m["status"] == "stale" and "step" not in m and "heading" not in m for m in early)
    g.start()
    rx.wait(lambda ms: any(m.get("step") == 32 for m in ms), timeout=10 + WAIT, what="step 32")
    assert g.wait(WAIT) and d.alive  # every frame written and read; block 33 still open
    assert d.stop() == 0 and not d.traceback
    ms = rx.wait(
        lambda ms: any(m.get("step") == 33 for m in ms), what="the last block, flushed at exit"
    )
    steps = steps_of(ms)
    assert [m["step"] for m in steps] == [0, 1, 2, 3, 4, 5, *range(26, 34)]
    assert all(m["samples"] == 10 for m in steps)
    after = next(m for m in steps if m["step"] == 26)
    assert after["gap_s"] == 20.0  # device seconds: the 20 empty blocks
    assert sum("gap_s" in m for m in steps) == 1
    hole = [m for m in ms[ms.index(steps[4]) + 1 : ms.index(steps[5])]]
    assert hole and all(
        m["status"] == "stale" and m["step"] == 4 and m["heading"] == steps[4]["heading"]
        for m in hole
    )
    assert (
        0.5 < after["yaw"] - steps[5]["yaw"] < 1.5
    )  # one step of a 1 deg/s turn: no 20 s invented
    assert d.count("device_lost") == 0 and d.named("stop")[-1]["reconnects"] == 0


# --------------------------------------------------------------------------- 3. dead peers


def closed_port(family: int = socket.AF_INET) -> int:
    s = socket.socket(family, socket.SOCK_DGRAM)
    s.bind(("::1" if family == socket.AF_INET6 else "127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there any more: ICMP port unreachable
    return port


def has_ipv6_loopback() -> bool:
    try:
        s = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        s.bind(("::1", 0))
        s.close()
        return True
    except OSError:
        return False


@pytest.mark.slow
def test_dead_peers_neither_stop_nor_slow_the_daemon(fake_gyro, hdrd, receivers):
    """The same drive read twice, once publishing also to destinations that refuse, do not
    resolve or do not answer: the live receiver gets the same steps, all of them, one per
    device second, in the same order."""
    profile = builtin_profile("constant", minutes=2, rate_dps=1.5, noise_dps=0.05, lead_in_s=0)
    dead = [
        "--udp",
        f"127.0.0.1:{closed_port()}",
        "--udp",
        "no-such-host.invalid:9",
        "--udp",
        "192.0.2.1:9",
    ]
    dead += ["--nmea-udp", f"127.0.0.1:{closed_port()}", "--nmea-udp", "198.51.100.7:10110"]
    if has_ipv6_loopback():
        dead += ["--udp", f"[::1]:{closed_port(socket.AF_INET6)}"]
    runs: list[Msgs] = []
    for extra in ([], dead):
        g = fake_gyro(profile, speedup=0)
        rx = receivers()
        d = hdrd(
            *run_args(
                "--clock-rate", "0", "--port", g.path, "--bias", "0.0", "--udp", rx.addr, *extra
            )
        )
        g.start()
        rx.wait(lambda ms: len(ms) >= 119, what="119 steps")
        assert g.wait(WAIT) and d.alive
        assert d.stop() == 0 and not d.traceback
        runs.append(rx.wait(lambda ms: len(ms) >= 120, what="the last step"))
    plain, with_dead = ([{k: v for k, v in m.items() if k != "time"} for m in ms] for ms in runs)
    assert with_dead == plain
    assert [m["step"] for m in plain] == list(range(120))  # 120 device seconds, 120 steps


@pytest.mark.slow
def test_tail_that_comes_and_goes(fake_gyro, hdrd, receivers):
    """`hdrd tail` started and stopped three times on the daemon's port: each time it gets
    fresh steps; in between nothing listens there (refused) and the daemon carries on."""
    port = closed_port()
    g = fake_gyro(constant_turn(minutes=5, rate_dps=1.0), speedup=4)
    rx = receivers()
    d = hdrd(
        *run_args(
            "--clock-rate",
            "4",
            "--port",
            g.path,
            "--bias",
            "0",
            "--udp",
            f"127.0.0.1:{port}",
            "--udp",
            rx.addr,
        )
    )
    wait_port_open(d, g.path)
    g.start()
    last = -1
    for _ in range(3):
        t = subprocess.run(
            [
                sys.executable,
                "-m",
                "hdrd",
                "tail",
                "--listen",
                f"127.0.0.1:{port}",
                "--raw",
                "--count",
                "3",
            ],
            capture_output=True,
            check=False,
            timeout=WAIT,
        )
        assert t.returncode == 0, t.stderr.decode()
        got = [json.loads(x) for x in t.stdout.splitlines()]
        assert len(got) == 3 and [m["class"] for m in got] == ["HDR"] * 3
        assert got[0]["step"] > last and [m["step"] for m in got] == list(
            range(got[0]["step"], got[0]["step"] + 3)
        )
        last = got[-1]["step"]
        # the daemon goes on publishing to the port nobody listens on now
        rx.wait(
            lambda ms, last=last: bool(ms) and ms[-1]["step"] >= last + 3,
            what="steps while no tail runs",
        )
    assert d.alive
    assert d.stop() == 0 and not d.traceback
    steps = [m["step"] for m in rx.snapshot()]
    assert steps == list(range(len(steps)))  # nothing lost on the live destination meanwhile


@pytest.mark.slow
def test_stdout_closed_by_the_reader_mid_run(fake_gyro, hdrd, receivers):
    g = fake_gyro(constant_turn(minutes=5, rate_dps=1.0), speedup=4)
    rx = receivers()
    d = hdrd(
        *run_args(
            "--clock-rate", "4", "--port", g.path, "--bias", "0", "--stdout", "--udp", rx.addr
        ),
        stdout=subprocess.PIPE,
    )
    wait_port_open(d, g.path)
    g.start()
    out = d.proc.stdout
    assert out is not None
    lines = [json.loads(out.readline()) for _ in range(3)]
    assert [m["step"] for m in lines] == [0, 1, 2]
    out.close()  # the reader goes away, as `| head -n 3` does
    assert d.proc.wait(timeout=WAIT) == 0
    d.stop()
    assert not d.traceback
    assert d.count("output_closed") == 1 and d.named("stop")


# --------------------------------------------------------------------------- 5. signals and restarts


def standstill(minutes: float = 5.0, bias_dps: float = 0.37, noise_dps: float = 0.05) -> DriveLog:
    return builtin_profile(
        "standstill", minutes=minutes, bias_dps=bias_dps, noise_dps=noise_dps, lead_in_s=0
    )


@pytest.mark.slow
def test_sigterm_during_hdrd_calibrate_keeps_the_old_bias_file(fake_gyro, hdrd, tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    bias_file = state / "bias.yaml"
    save_bias(bias_file, BiasRecord(0.123, 0.01, 300, 30.0, 21.0, 1.7e9))
    old = bias_file.read_bytes()
    g = fake_gyro(standstill(), speedup=1)
    c = hdrd(
        "calibrate",
        "--port",
        g.path,
        "--seconds",
        "30",
        env={"STATE_DIRECTORY": str(state)},
        stdout=subprocess.PIPE,
    )
    g.start()
    out = c.proc.stdout
    assert out is not None
    first = out.readline().decode()
    assert first.startswith("calibrating")
    progress = out.readline().decode()  # "  1.0 / 30 s  mean ..."
    assert "/ 30 s" in progress
    assert c.stop() == 0
    assert any("interrupted" in line for line in c.other)
    assert bias_file.read_bytes() == old and sorted(os.listdir(state)) == ["bias.yaml"]


@pytest.mark.slow
def test_sigterm_during_startup_calibration(fake_gyro, hdrd, receivers, tmp_path):
    cfg = fast_config(tmp_path, calibration="  startup_s: 30\n")
    notify = receivers(tmp_path / "notify.sock")
    g = fake_gyro(standstill(), speedup=4)
    rx = receivers()
    d = hdrd(
        *run_args("--clock-rate", "4", "--config", str(cfg), "--port", g.path, "--udp", rx.addr),
        env={"NOTIFY_SOCKET": str(tmp_path / "notify.sock")},
    )
    wait_port_open(d, g.path)
    g.start()
    ms = rx.wait(lambda ms: len(steps_of(ms)) >= 2, what="calibrating steps")
    assert all(m["status"] == "calibrating" and "heading" not in m for m in steps_of(ms))
    assert d.stop() == 0 and not d.traceback
    assert d.named("stop") and d.count("calibrated") == 0
    seen = notify.wait(lambda xs: "STOPPING=1" in xs, what="STOPPING=1")
    assert "READY=1" not in seen  # the bias was never known
    assert any(s.startswith("STATUS=calibrating") for s in seen)


@pytest.mark.slow
@pytest.mark.parametrize("protocol", ["hdr-bin", "hdr-text"])
def test_sigterm_during_a_burst_of_bad_frames(fake_gyro, hdrd, receivers, tmp_path, protocol):
    g = fake_gyro(standstill(), speedup=4, protocol=protocol, crc_errors=0.9, garbage=0.9, seed=11)
    rx = receivers()
    d = hdrd(
        *run_args(
            "--clock-rate",
            "4",
            "--port",
            g.path,
            "--protocol",
            protocol,
            "--bias",
            "0.37",
            "--udp",
            rx.addr,
        )
    )
    wait_port_open(d, g.path)
    g.start()
    ms = rx.wait(lambda ms: ms and ms[-1]["bad_frames"] >= 30, what="30 bad frames")
    assert d.stop() == 0 and not d.traceback
    stop = d.named("stop")[-1]
    assert stop["bad_frames"] >= ms[-1]["bad_frames"]
    assert d.count("bad_frames") >= 1  # logged (rate-limited), not per frame
    assert d.count("bad_frames") < stop["bad_frames"]


@pytest.mark.slow
def test_sighup_with_broken_or_missing_config_keeps_the_old_one(
    fake_gyro, hdrd, receivers, tmp_path
):
    rx = receivers()
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(f"output:\n  udp: ['{rx.addr}']\n  heading0_deg: 0\n")
    g = fake_gyro(constant_turn(minutes=5, rate_dps=1.0), speedup=4)
    d = hdrd(*run_args("--clock-rate", "4", "--config", str(cfg), "--port", g.path, "--bias", "0"))
    wait_port_open(d, g.path)
    g.start()
    rx.wait(lambda ms: len(ms) >= 2, what="2 steps")
    for k, breakage in enumerate(["syntax", "missing", "not a mapping"], 1):
        if breakage == "syntax":
            cfg.write_text("output:\n  udp: [\n")
        elif breakage == "missing":
            cfg.unlink()
        else:
            cfg.write_text("- just\n- a list\n")
        n = len(rx.snapshot())
        d.proc.send_signal(signal.SIGHUP)
        d.wait_event("config_reload_failed", k)
        rx.wait(
            lambda ms, n=n: len(ms) >= n + 3, what=f"steps after SIGHUP with a {breakage} config"
        )
        assert d.alive
    failed = d.named("config_reload_failed")
    assert all("\n" not in e["error"] and str(cfg) in e["error"] for e in failed)
    assert "no such file" in failed[1]["error"]
    cfg.write_text(f"output:\n  udp: ['{rx.addr}']\n  heading0_deg: 90\n")
    d.proc.send_signal(signal.SIGHUP)
    d.wait_event("config_reloaded")
    n = len(rx.snapshot())
    ms = rx.wait(lambda ms: len(ms) >= n + 2, what="steps after a good SIGHUP")
    # heading0 is the heading at start: the reload keeps the heading (and says so)
    assert ms[-1]["heading"] == pytest.approx((0.0 - ms[-1]["yaw"]) % 360.0)
    assert [e["key"] for e in d.named("config_reload_partial")] == ["output.heading0_deg"]
    steps = [m["step"] for m in ms]
    assert steps == list(range(len(steps)))  # one destination, kept throughout, nothing lost
    assert d.stop() == 0 and not d.traceback


@pytest.mark.slow
def test_restart_resumes_with_the_saved_bias(fake_gyro, hdrd, receivers, tmp_path):
    """`hdrd calibrate` writes $STATE_DIRECTORY/bias.yaml; `hdrd run` started with the same
    STATE_DIRECTORY and no bias option uses it from its first step (no "calibrating"), and so
    does the next start, as under systemd's StateDirectory=."""
    state = tmp_path / "state"
    state.mkdir()
    env = {"STATE_DIRECTORY": str(state)}
    g = fake_gyro(standstill(minutes=1, bias_dps=0.37), speedup=0)
    g.start()
    c = hdrd("calibrate", "--port", g.path, "--seconds", "3", env=env)
    assert c.proc.wait(timeout=WAIT) == 0, c.other
    c.stop()
    bias_file = state / "bias.yaml"
    assert (bias_file.stat().st_mode & 0o777) == 0o644
    rec = load_bias(bias_file)
    assert rec.bias_dps == pytest.approx(0.37, abs=0.02)
    for _ in range(2):
        g = fake_gyro(standstill(minutes=1, bias_dps=0.37), speedup=0)
        rx = receivers()
        d = hdrd(*run_args("--clock-rate", "0", "--port", g.path, "--udp", rx.addr), env=env)
        g.start()
        ms = rx.wait(lambda ms: len(ms) >= 3, what="3 steps")
        assert d.stop() == 0
        assert all(m["bias"] == rec.bias_dps and m["status"] != "calibrating" for m in ms)
        start = d.named("start")[0]
        assert start["bias"] == str(bias_file) and start["bias_dps"] == rec.bias_dps
        assert d.count("calibrated") == 0
    assert load_bias(bias_file) == rec  # read, never rewritten by the daemon


# --------------------------------------------------------------------------- 1. rails, live


@pytest.mark.slow
def test_saturation_is_flagged_in_the_daemons_messages(fake_gyro, hdrd, receivers):
    """A turn beyond the CRS03-04's 200 deg/s (the ADC at its rail) is flagged, not a crash,
    and not a rate: those steps hold the heading and say ``saturated``."""
    t = np.arange(60) / 10.0
    omega = np.select([t < 2, t < 4, t < 5], [0.0, 300.0, -300.0], 0.0)
    g = fake_gyro(DriveLog(t=t, omega=omega), speedup=0)
    rx = receivers()
    d = hdrd(*run_args("--clock-rate", "0", "--port", g.path, "--bias", "0", "--udp", rx.addr))
    g.start()
    rx.wait(lambda ms: len(ms) >= 5, what="5 steps")
    assert d.stop() == 0 and not d.traceback
    ms = rx.wait(lambda ms: len(ms) >= 6, what="6 steps")
    assert [m.get("saturated", 0) for m in ms] == [0, 0, 10, 10, 10, 0]
    assert [m["status"] for m in ms[2:5]] == ["saturated"] * 3
    assert all("omega" not in m and m["heading"] == ms[1]["heading"] for m in ms[2:5])
