#!/usr/bin/env python3
"""Live: what `hdrd run` costs, fed by the fake gyro on a pty at 100 Hz, 1 kHz and 18,750 Hz.

    python bench/live.py [--seconds 60] [--rates 100,1000,18750] [--load N] [--no-write]

Takes about 3 * (seconds + 10) s. For each frame rate the daemon runs as a process
(``hdrd run --port PTY --bias 0.1 --udp 127.0.0.1:PORT``, the console script) on a pty written
in real time by :class:`hdrd.sim.fakegyro.FakeGyro` (a simulated "mixed" drive, no faults), and we
measure, over the ``--seconds`` after its first step message (imports and start-up excluded):

- **CPU share of one core**: utime + stime of the daemon (``/proc/<pid>/stat``, clock ticks)
  over the wall time of the window;
- **peak RSS**: ``VmHWM`` of ``/proc/<pid>/status`` at the end (the whole run, start-up
  included);
- **step latency**: from the write of the frame that closes a step (the first frame of the next
  T-block; blocks are cut from the first frame the daemon read) to the arrival of that step's
  UDP datagram. The fake gyro's writer notes ``time.time_ns()`` just *before* each write (a
  write carries every frame due, usually one); the receiving socket has the kernel stamp each
  datagram as it arrives (``SO_TIMESTAMPNS``, the same CLOCK_REALTIME), so neither stamp waits
  for this process's threads to be scheduled. The write stamp is taken before the writer's
  poll and write system calls, so the figure is an upper bound.

``--load N`` runs N busy-looping processes meanwhile, to see what a machine busy with other
work does to the figures (CPU time per wake-up grows with cold caches; latency with the wait
for a core).

Targets at 1 kHz: <= 2 % of one core, peak RSS <= 60 MB, p99 latency <= 2 ms.
Prints the figures and writes them, with the machine's description, in its section of
bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import hdrd_command, machine, machine_line, ratio, write_section

from hdrd.io.wire.clocks import unwrap_us
from hdrd.sim.fakegyro import FakeGyro

SO_TIMESTAMPNS = getattr(
    socket, "SO_TIMESTAMPNS", 35
)  # Linux asm-generic value; not exported by Python 3.11
BIAS_DPS = 0.1
T_S = 1.0
CPU_TARGET = 0.02
RSS_TARGET_MB = 60.0
P99_TARGET_MS = 2.0
WAIT = 60.0


class TimedFakeGyro(FakeGyro):
    """The fake gyro, noting when each frame was written (``write_ns[k]``, CLOCK_REALTIME ns,
    taken just before the write that carried frame k; -1 = not written)."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self.write_ns = np.full(self.frames.shape[0], -1, np.int64)
        self._t_write = 0

    def _write(self, data: bytes) -> bool:
        self._t_write = time.time_ns()
        return super()._write(data)

    def _commit(self, tally: Any, written: bool) -> None:
        if written:
            self.write_ns[tally.idx] = self._t_write
        super()._commit(tally, written)


class Receiver(threading.Thread):
    """UDP datagrams from the daemon with their kernel arrival stamps (CLOCK_REALTIME ns)."""

    def __init__(self) -> None:
        super().__init__(name="live-udp", daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.addr = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.steps: list[tuple[dict[str, Any], int]] = []
        self.stale = threading.Event()
        self.first_step = threading.Event()
        self._done = threading.Event()

    def run(self) -> None:
        while True:
            try:
                data, anc, _, _ = self.sock.recvmsg(65536, 64)
            except TimeoutError:
                if self._done.is_set():
                    return
                continue
            except OSError:
                return
            arrived = -1
            for level, kind, payload in anc:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                    sec, nsec = struct.unpack("@ll", payload[: struct.calcsize("@ll")])
                    arrived = sec * 1_000_000_000 + nsec
            if arrived < 0:
                arrived = time.time_ns()  # no kernel stamp: ours (later, so an upper bound too)
            m = json.loads(data)
            if m.get("status") == "stale":
                self.stale.set()
            elif "step" in m and "samples" in m:
                self.steps.append((m, arrived))
                self.first_step.set()

    def close(self) -> None:
        self._done.set()
        self.join(timeout=5)
        self.sock.close()


def cpu_ticks(pid: int) -> int:
    """utime + stime of a process, clock ticks (/proc/<pid>/stat fields 14 and 15)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    rest = stat[stat.rindex(")") + 2 :].split()
    return int(rest[11]) + int(rest[12])


def status_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"no {key} for pid {pid}")


@dataclass
class LiveResult:
    hz: float
    window_s: float
    cpu_s: float
    cpu_share: float
    rss_peak_mb: float
    rss_end_mb: float
    steps: int
    latencies_ms: list[float]
    samples_ok: bool

    @property
    def p50_ms(self) -> float:
        return float(np.percentile(self.latencies_ms, 50))

    @property
    def p99_ms(self) -> float:
        return float(np.percentile(self.latencies_ms, 99))

    @property
    def max_ms(self) -> float:
        return float(np.max(self.latencies_ms))


def measure(hz: float, seconds: float, seed: int = 1) -> LiveResult:
    """One run of the daemon at ``hz`` (see the module doc)."""
    from hdrd.sim import simulate_drive

    # Lead-in standstill 5 s (start-up, first step), then the measured window and 3 s spare.
    profile = simulate_drive("mixed", (seconds + 3.0) / 60.0, seed, hz=hz, lead_in_s=5.0)
    with tempfile.TemporaryDirectory(prefix="hdrd-live-") as tmp:
        tmpd = Path(tmp)
        cfg = tmpd / "hdrd.yaml"
        cfg.write_text("device:\n  stale_after_s: 0.5\n")
        g = TimedFakeGyro(profile, speedup=1.0, link=tmpd / "gyro", seed=seed)
        rx = Receiver()
        rx.start()
        env = _daemon_env(tmpd)
        proc: subprocess.Popen[bytes] | None = None
        try:
            g.open()
            cmd = [*hdrd_command(), "run", "--config", str(cfg), "--port", str(g.link), "--bias",
                   str(BIAS_DPS), "--udp", rx.addr, "--log-format", "json"]  # fmt: skip
            proc = subprocess.Popen(
                cmd,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=env,
            )
            if not rx.stale.wait(WAIT):  # the port is open and the loop runs, no data yet
                raise RuntimeError("the daemon sent no stale report")
            g.start()
            if not rx.first_step.wait(WAIT):
                raise RuntimeError("no step message from the daemon")
            c0, w0 = cpu_ticks(proc.pid), time.monotonic()
            time.sleep(seconds)
            c1, w1 = cpu_ticks(proc.pid), time.monotonic()
            g.stop()
            time.sleep(1.5)  # the last steps' datagrams
            peak = status_kb(proc.pid, "VmHWM")
            rss_end = status_kb(proc.pid, "VmRSS")
            proc.terminate()
            proc.wait(timeout=WAIT)
        finally:
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
            g.close()
            rx.close()
    tick = os.sysconf("SC_CLK_TCK")
    cpu_s = (c1 - c0) / tick
    lat, samples_ok = _latencies(g, rx)
    return LiveResult(
        hz=hz,
        window_s=w1 - w0,
        cpu_s=cpu_s,
        cpu_share=cpu_s / (w1 - w0),
        rss_peak_mb=peak / 1024,
        rss_end_mb=rss_end / 1024,
        steps=len(lat),
        latencies_ms=lat,
        samples_ok=samples_ok,
    )


def _daemon_env(state: Path) -> dict[str, str]:
    """The environment of the daemon: its state in ``state``, no systemd notification."""
    env = dict(os.environ, STATE_DIRECTORY=str(state))
    for name in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
        env.pop(name, None)
    return env


def _latencies(g: TimedFakeGyro, rx: Receiver) -> tuple[list[float], bool]:
    """Each step's latency (ms) from the write of the frame that closed its block to the
    datagram's arrival, and whether every step holds the samples of its block."""
    # Block edges from the first frame the daemon read: every frame was written to an open port.
    written = np.flatnonzero(g.write_ns >= 0)
    t_us, _ = unwrap_us(g.frames["t_us"][written])
    rel = t_us - t_us[0]
    T_us = round(T_S * 1e6)
    lat: list[float] = []
    samples_ok = True
    for m, arrived in rx.steps:
        i = int(m["step"])
        k = int(np.searchsorted(rel, (i + 1) * T_us, side="left"))  # first frame of a later block
        if k >= written.shape[0]:
            continue  # closed by the final flush at SIGTERM, not by a frame
        expected = int(np.count_nonzero((rel >= i * T_us) & (rel < (i + 1) * T_us)))
        samples_ok &= int(m["samples"]) == expected
        lat.append((arrived - int(g.write_ns[written[k]])) / 1e6)
    return lat, samples_ok


def report(results: list[LiveResult], seconds: float, load: int = 0) -> str:
    cmd = " ".join(
        ["hdrd", "run", "--port", "PTY", "--bias", str(BIAS_DPS), "--udp", "127.0.0.1:PORT"]
    )
    lines = [
        f"`python bench/live.py --seconds {seconds:g}{f' --load {load}' if load else ''}` on "
        f"{machine_line()}"
        + (
            f"; {load} busy-looping processes ran beside it (the machine has 2 cores)."
            if load
            else "."
        ),
        "",
        (
            f"`{cmd}` (a process) on a pty written in real time by the fake gyro; CPU over the "
            f"{seconds:g} s after the first step; peak RSS of the whole run; latency from the write "
            "of the step-closing frame to the kernel's arrival stamp of the step's UDP datagram "
            "(an upper bound)."
        ),
        "",
        "| frames/s | CPU, % of one core | peak RSS (VmHWM) | latency p50 | p99 | max | steps | samples per step as sent |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        lines.append(
            f"| {r.hz:,.0f} | {100 * r.cpu_share:.2f} % ({r.cpu_s:.2f} s in {r.window_s:.1f} s) | "
            f"{r.rss_peak_mb:.1f} MB | {r.p50_ms:.2f} ms | {r.p99_ms:.2f} ms | {r.max_ms:.2f} ms | {r.steps} | "
            f"{'yes' if r.samples_ok else 'NO'} |"
        )
    k = next((r for r in results if r.hz == 1000), None)
    if k is not None:
        lines += [
            "",
            (
                "Targets at 1 kHz (ratio > 1 = inside the target): "
                f"CPU {100 * k.cpu_share:.2f} % vs <= {100 * CPU_TARGET:g} % "
                f"({ratio(k.cpu_share, CPU_TARGET, False)}); "
                f"peak RSS {k.rss_peak_mb:.1f} vs <= {RSS_TARGET_MB:g} MB "
                f"({ratio(k.rss_peak_mb, RSS_TARGET_MB, False)}); "
                f"p99 {k.p99_ms:.2f} vs <= {P99_TARGET_MS:g} ms "
                f"({ratio(k.p99_ms, P99_TARGET_MS, False)})."
            ),
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="measured window per rate, s")
    ap.add_argument(
        "--rates",
        default="100,1000,18750",
        help="frame rates, Hz, comma-separated (18,750: a 3 Mbaud link's limit)",
    )
    ap.add_argument(
        "--load",
        type=int,
        default=0,
        metavar="N",
        help="run N busy processes meanwhile (a machine busy with other work)",
    )
    ap.add_argument("--no-write", action="store_true", help="print only; do not write RESULTS.md")
    a = ap.parse_args(argv)
    m = machine()
    print(machine_line(m), flush=True)
    results = []
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.load)]
    try:
        for hz in (float(x) for x in a.rates.split(",")):
            print(f"{hz:g} Hz for {a.seconds:g} s ...", flush=True)
            results.append(measure(hz, a.seconds))
    finally:
        for b in busy:
            b.kill()
            b.wait()
    for r in results:
        print(
            f"  CPU {100 * r.cpu_share:.2f} % of one core, peak RSS {r.rss_peak_mb:.1f} MB, latency p50 "
            f"{r.p50_ms:.2f} ms p99 {r.p99_ms:.2f} ms max {r.max_ms:.2f} ms over {r.steps} steps, "
            f"samples as sent: {r.samples_ok}",
            flush=True,
        )
    text = report(results, a.seconds, a.load)
    beside = f" beside {a.load} busy process{'es' if a.load > 1 else ''}" if a.load else ""
    title = f"Live daemon{beside}: CPU, memory and step latency"
    write_section("speed", title, text, write=not a.no_write)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
