#!/usr/bin/env python3
"""Soak: `hdrd run` against the fake gyro at 100 Hz for hours of device time, with faults.

    python bench/soak.py [--hours 6] [--speedup 200] [--hz 100] [--drive mixed] [--seed 1]
                         [--garbage 0.002] [--crc-errors 0.002] [--drop 0.002]
                         [--pull-every-min 30] [--pull-for 2] [--json FILE]

The daemon runs as a process (`python -m hdrd run`) on a pty written by
:class:`hdrd.sim.fakegyro.FakeGyro` with a simulated drive (``hdrd.sim``), accelerated
``--speedup`` times, with garbage, CRC errors and dropped frames at the given per-frame
probabilities throughout, and a cable pull (pty and its symlink gone, ``--pull-for`` wall
seconds; the device clock runs on, so ``pull-for * speedup`` device seconds are never sent)
every ``--pull-every-min`` minutes of device time. No bias file: the daemon measures the bias
at start. It publishes JSON over UDP to a receiver here; its structured log is read from
stderr; its memory is read from /proc/<pid>/status (VmRSS) every few seconds.

Expected, from what the fake gyro delivered (``FakeGyro.delivered``, ``injected``):

- steps: per connection, the number of distinct T-blocks the delivered frames fall in (blocks
  are cut from the connection's first sample: the daemon resynchronises after a reconnect);
- samples: every delivered frame is in exactly one published step;
- bad frames: the CRC-damaged frames (plus any sync pattern a damaged frame holds);
- reconnects: one per cable pull.

So that a reconnect never races the fake's next write against the serial port's input flush
at open (a real device's bytes would be lost there too, but then the counts could not be
exact), the fake resumes writing after a pull only once the daemon has logged
``device_back``; it starts writing once the daemon's first "stale" report shows its port is
open. Results: bench/RESULTS.md, "Soak: six hours of device time with faults and cable pulls".
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from hdrd.io.wire.clocks import unwrap_us
from hdrd.sim.fakegyro import FakeGyro

WAIT = 60.0  # upper bound for anything to happen; only a hung daemon reaches it


@dataclass
class SoakResult:
    """What a soak measured; ``ok`` when every count is as expected."""

    device_hours: float
    speedup: float
    hz: float
    wall_s: float
    frames_total: int
    frames_delivered: int
    samples_published: int
    steps_expected: int
    steps_published: int
    steps_in_order: bool
    """Step numbers increase; they skip (by the time the cable was out) only at reconnects."""
    stale_reports: int
    bad_injected: int
    bad_counted: int
    garbage_events: int
    dropped: int
    pulls: int
    reconnects: int
    device_lost_events: int
    exit_code: int
    rss_start_kb: int
    rss_end_kb: int
    rss_max_kb: int
    traceback: bool
    bias_dps: float | None
    events: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return (
            self.steps_published == self.steps_expected
            and self.steps_in_order
            and self.samples_published == self.frames_delivered
            and self.bad_counted == self.bad_injected
            and self.reconnects == self.pulls == self.device_lost_events
            and self.exit_code == 0
            and not self.traceback
        )


class _Receiver(threading.Thread):
    """UDP JSON lines from the daemon, kept in order."""

    def __init__(self) -> None:
        super().__init__(name="soak-udp", daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.addr = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.messages: list[dict[str, Any]] = []
        self.stale = threading.Event()
        self.stale_count = 0
        self._done = threading.Event()

    def run(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                if self._done.is_set():
                    return  # stopped, and nothing more queued
                continue
            except OSError:
                return
            m = json.loads(data)
            if m.get("status") == "stale":
                self.stale_count += 1
                self.stale.set()
            else:
                self.messages.append(m)

    def close(self) -> None:
        self._done.set()
        self.join(timeout=5)
        self.sock.close()


class _Log(threading.Thread):
    """The daemon's JSON log events from stderr, counted by name; non-JSON lines kept."""

    def __init__(self, stream: Any) -> None:
        super().__init__(name="soak-log", daemon=True)
        self.stream = stream
        self.events: list[dict[str, Any]] = []
        self.other: list[str] = []
        self.cond = threading.Condition()

    def run(self) -> None:
        for raw in self.stream:
            line = raw.decode("utf-8", "replace").rstrip("\n")
            try:
                ev = json.loads(line)
            except json.JSONDecodeError:
                self.other.append(line)
                continue
            with self.cond:
                self.events.append(ev)
                self.cond.notify_all()

    def count(self, name: str) -> int:
        with self.cond:
            return sum(1 for e in self.events if e.get("event") == name)

    def wait_count(self, name: str, n: int, timeout: float = WAIT) -> bool:
        with self.cond:
            return self.cond.wait_for(
                lambda: sum(1 for e in self.events if e.get("event") == name) >= n, timeout
            )


def rss_kb(pid: int) -> int:
    """Resident set size of a process, kB (VmRSS in /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for pid {pid}")


def expected_steps(g: FakeGyro, T_s: float = 1.0) -> int:
    """Distinct T-blocks of the delivered frames, per connection (cut at the pulls)."""
    t = g.t_s
    edges = [0.0, *g.pull_at, float("inf")]
    T_us = round(T_s * 1e6)
    total = 0
    for a, b in itertools.pairwise(edges):
        sel = g.delivered & (t >= a) & (t < b)
        if not sel.any():
            continue
        tu, _ = unwrap_us(g.frames["t_us"][sel])
        total += int(np.unique((tu - tu[0]) // T_us).size)
    return total


def _pull_times(profile: Any, pull_every_min: float) -> list[float]:
    """Device times (s) of the cable pulls: every ``pull_every_min`` minutes, none in the last
    minute, none at all for 0."""
    if pull_every_min <= 0:
        return []
    first_pull = pull_every_min * 60.0
    return list(np.arange(first_pull, profile.t[-1] - 60.0, pull_every_min * 60.0))


def _daemon_command(tmpd: Path, link: Path, udp: str, speedup: float) -> list[str]:
    """``python -m hdrd run`` on the fake's port, publishing to ``udp``, with a configuration
    (short reconnect delays) and a state folder in ``tmpd``."""
    (tmpd / "state").mkdir()
    cfg = tmpd / "hdrd.yaml"
    cfg.write_text(
        "device:\n  stale_after_s: 0.5\n  reconnect_min_s: 0.1\n  reconnect_max_s: 1.0\nlog:\n  bad_frame_interval_s: 5.0\n"
    )
    return [
        sys.executable, "-m", "hdrd", "run", "--clock-rate", str(speedup), "--config", str(cfg),
        "--port", str(link), "--udp", udp, "--log-format", "json",
    ]  # fmt: skip


def _watch(
    g: FakeGyro, proc: subprocess.Popen[bytes], rx: _Receiver, rss: list[int], progress: bool
) -> None:
    """Until the fake has written everything (or the daemon is gone): the daemon's RSS (kB)
    every 2 s once it publishes, and the progress line."""
    next_rss = 0.0
    n_frames = g.frames.shape[0]
    while not g.wait(0.5):
        if proc.poll() is not None:
            break
        now = time.monotonic()
        if len(rx.messages) >= 60 and now >= next_rss:
            rss.append(rss_kb(proc.pid))
            next_rss = now + 2.0
        if progress:
            done = int(g.delivered.sum())
            print(
                f"\r  {done / n_frames:6.1%} of {n_frames:,} frames, {len(rx.messages):,} steps, RSS {rss[-1] if rss else 0} kB",
                end="",
                file=sys.stderr,
                flush=True,
            )


def _run_daemon(
    g: FakeGyro, rx: _Receiver, argv: list[str], env: dict[str, str], progress: bool
) -> tuple[int, _Log, list[int]]:
    """The daemon run on the fake's data to its end: its exit status, its log, its RSS
    samples (kB). The fake and the receiver are closed after it."""
    proc: subprocess.Popen[bytes] | None = None
    log: _Log | None = None
    rss: list[int] = []
    try:
        g.open()
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        log = _Log(proc.stderr)
        log.start()
        reopened = log

        def resume_after_reconnect() -> None:
            # Runs in the fake's writer thread once the new pty is up: hold the next
            # write until the daemon has reopened the port (and flushed its input).
            reopened.wait_count("device_back", g.injected.pulls)

        g.on_pull_end = resume_after_reconnect  # type: ignore[method-assign]
        if not rx.stale.wait(WAIT):  # the port is open: the loop is running, no data yet
            raise RuntimeError("the daemon sent no stale report before data")
        g.start()
        _watch(g, proc, rx, rss, progress)
        if g.error is not None:
            raise RuntimeError(f"the fake gyro failed: {g.error!r}")
        # Everything written and read: the daemon goes stale once it has parsed it all.
        rx.stale.clear()
        rx.stale.wait(WAIT)
        if proc.poll() is None:
            rss.append(rss_kb(proc.pid))
            proc.terminate()
        exit_code = proc.wait(timeout=WAIT)
        log.join(timeout=10)
    finally:
        _stop(proc, log)
        g.close()
        rx.close()
    return exit_code, log, rss


def _stop(proc: subprocess.Popen[bytes] | None, log: _Log | None) -> None:
    """The daemon killed if it still runs, its log read to its end and our end of the pipe
    closed."""
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait()
    if proc is not None and proc.stderr is not None:
        if log is not None:
            log.join(timeout=10)  # the log is read to its end: close our end of the pipe
        proc.stderr.close()


def _result(
    g: FakeGyro, rx: _Receiver, log: _Log, rss: list[int], exit_code: int, wall: float,
    speedup: float, hz: float,
) -> SoakResult:  # fmt: skip
    """What was measured, beside what the fake delivered and injected."""
    msgs = rx.messages
    steps = [m["step"] for m in msgs]
    stop: dict[str, Any] = next((e for e in reversed(log.events) if e.get("event") == "stop"), {})
    names: dict[str, int] = {}
    for e in log.events:
        names[e["event"]] = names.get(e["event"], 0) + 1
    pairs = list(itertools.pairwise(steps))
    return SoakResult(
        device_hours=float(g.t_s[-1]) / 3600.0,
        speedup=speedup,
        hz=hz,
        wall_s=wall,
        frames_total=int(g.frames.shape[0]),
        frames_delivered=int(g.delivered.sum()),
        samples_published=sum(int(m["samples"]) for m in msgs),
        steps_expected=expected_steps(g),
        steps_published=len(msgs),
        steps_in_order=all(b > a for a, b in pairs)
        and sum(b - a > 1 for a, b in pairs) <= g.injected.pulls,
        stale_reports=rx.stale_count,
        bad_injected=g.injected.expected_bad_frames,
        bad_counted=int(stop.get("bad_frames", -1)),
        garbage_events=g.injected.garbage_events,
        dropped=g.injected.dropped,
        pulls=g.injected.pulls,
        reconnects=int(stop.get("reconnects", -1)),
        device_lost_events=names.get("device_lost", 0),
        exit_code=exit_code,
        rss_start_kb=rss[0] if rss else 0,
        rss_end_kb=rss[-1] if rss else 0,
        rss_max_kb=max(rss) if rss else 0,
        traceback=any("Traceback" in line for line in log.other),
        bias_dps=next((m["bias"] for m in msgs if "bias" in m), None),
        events=names,
    )


def soak(
    hours: float = 6.0,
    speedup: float = 200.0,
    hz: float = 100.0,
    drive: str = "mixed",
    seed: int = 1,
    garbage: float = 0.002,
    crc_errors: float = 0.002,
    drop: float = 0.002,
    pull_every_min: float = 30.0,
    pull_for_s: float = 2.0,
    workdir: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> SoakResult:
    """Run one soak (see the module doc) and return what it measured."""
    from hdrd.sim import simulate_drive

    profile = simulate_drive(drive, hours * 60.0, seed, hz=hz)
    with tempfile.TemporaryDirectory(prefix="hdrd-soak-", dir=workdir) as tmp:
        tmpd = Path(tmp)
        link = tmpd / "gyro"
        g = FakeGyro(
            profile,
            speedup=speedup,
            link=link,
            garbage=garbage,
            crc_errors=crc_errors,
            drop=drop,
            pull_at=_pull_times(profile, pull_every_min),
            pull_for=pull_for_s,
            seed=seed,
        )
        rx = _Receiver()
        rx.start()
        argv = _daemon_command(tmpd, link, rx.addr, speedup)
        env = dict(os.environ, STATE_DIRECTORY=str(tmpd / "state"))
        env.pop("NOTIFY_SOCKET", None)
        env.pop("WATCHDOG_USEC", None)
        t_wall = time.monotonic()
        exit_code, log, rss = _run_daemon(g, rx, argv, env, progress)
        if progress:
            print(file=sys.stderr)
        return _result(g, rx, log, rss, exit_code, time.monotonic() - t_wall, speedup, hz)


def report(r: SoakResult) -> str:
    mb = 1024.0
    growth = (r.rss_end_kb - r.rss_start_kb) / mb
    bias = "none" if r.bias_dps is None else f"{r.bias_dps:+.4f} deg/s"
    lines = [
        f"soak: {r.device_hours:.2f} h of device time at {r.hz:g} Hz, speedup {r.speedup:g}, "
        + f"{r.wall_s:.0f} s wall",
        f"  steps published {r.steps_published:,}, expected {r.steps_expected:,} "
        + f"(numbers in order, skipping only at reconnects: {r.steps_in_order}); stale reports {r.stale_reports}",
        f"  frames delivered {r.frames_delivered:,} of {r.frames_total:,}; "
        + f"samples in published steps {r.samples_published:,}",
        f"  bad frames counted {r.bad_counted:,}, injected {r.bad_injected:,}; "
        + f"garbage runs {r.garbage_events:,}, dropped frames {r.dropped:,}",
        f"  cable pulls {r.pulls}, device_lost {r.device_lost_events}, reconnects {r.reconnects}",
        f"  daemon RSS start {r.rss_start_kb / mb:.1f} MB, end {r.rss_end_kb / mb:.1f} MB, "
        + f"max {r.rss_max_kb / mb:.1f} MB (growth {growth:+.1f} MB)",
        f"  bias measured at start {bias}; exit status {r.exit_code}; traceback: {r.traceback}",
        f"  log events: {', '.join(f'{k} {v}' for k, v in sorted(r.events.items()))}",
        f"  {'OK' if r.ok else 'FAILED'}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, default=6.0, help="device time, h")
    ap.add_argument("--speedup", type=float, default=200.0)
    ap.add_argument("--hz", type=float, default=100.0, help="frame rate, Hz")
    ap.add_argument("--drive", default="mixed")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--garbage", type=float, default=0.002, help="probability of garbage before a frame"
    )
    ap.add_argument(
        "--crc-errors", type=float, default=0.002, help="probability of a corrupted frame"
    )
    ap.add_argument("--drop", type=float, default=0.002, help="probability of a dropped frame")
    ap.add_argument(
        "--pull-every-min",
        type=float,
        default=30.0,
        help="a cable pull every this many device minutes (0: none)",
    )
    ap.add_argument("--pull-for", type=float, default=2.0, help="how long a pull lasts, wall s")
    ap.add_argument("--json", metavar="FILE", help="write the result as JSON")
    args = ap.parse_args(argv)
    print(
        f"python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cores",
        flush=True,
    )
    r = soak(
        args.hours,
        args.speedup,
        args.hz,
        args.drive,
        args.seed,
        args.garbage,
        args.crc_errors,
        args.drop,
        args.pull_every_min,
        args.pull_for,
        progress=sys.stderr.isatty(),
    )
    print(report(r), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({**asdict(r), "ok": r.ok}, indent=2) + "\n")
    return 0 if r.ok else 1


if __name__ == "__main__":
    sys.exit(main())
