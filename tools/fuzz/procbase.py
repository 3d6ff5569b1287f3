"""The pieces every process-level fuzz run of tools/fuzz uses (tools/fuzz/process.py says what
the runs are and what they check): a run's result, the environment and command of ``hdrd``, a
process's peak memory, its stderr read line by line, a UDP receiver of its steps, stopping it,
and checking that it started and still publishes."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]

__all__ = [
    "HDRD",
    "Lines",
    "ProcResult",
    "RELOAD_EVENTS",
    "SILENCE_S",
    "Udp",
    "hdrd_env",
    "hwm_mb",
    "reap",
    "still_publishing",
    "stop_daemon",
    "wait_started",
]


@dataclass
class ProcResult:
    surface: str
    run: str
    inputs: int = 0
    processes: int = 0
    seconds: float = 0.0
    exits: dict[str, int] = field(default_factory=dict)
    tracebacks: int = 0
    dead: int = 0
    failures: list[str] = field(default_factory=list)
    peak_rss_mb: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not (self.tracebacks or self.dead or self.failures)

    def fail(self, text: str) -> None:
        if len(self.failures) < 20:
            self.failures.append(text[:500])

    def exit(self, rc: int | None) -> None:
        k = str(rc)
        self.exits[k] = self.exits.get(k, 0) + 1

    def describe(self) -> str:
        exits = ", ".join(f"{k}: {v:,}" for k, v in sorted(self.exits.items()))
        lines = [
            f"process {self.surface} / {self.run}: {self.inputs:,} inputs, {self.processes} "
            f"process(es), {self.seconds:.0f} s; exit statuses {{{exits}}}; tracebacks "
            f"{self.tracebacks}, dead {self.dead}; peak RSS {self.peak_rss_mb:.0f} MB",
        ]
        lines += [f"  note: {n}" for n in self.notes]
        lines += [f"  FAILURE: {f}" for f in self.failures]
        lines.append(f"  {'OK' if self.ok else 'FAILED'}")
        return "\n".join(lines)


def hdrd_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("NOTIFY_SOCKET", None)
    env.pop("WATCHDOG_USEC", None)
    env.update(extra)
    return env


HDRD = [sys.executable, "-m", "hdrd"]


def hwm_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


class Lines(threading.Thread):
    """Reads a pipe to its end, keeping the count of lines, the last ones, and what a check
    found (a Traceback; a non-printable line)."""

    def __init__(self, stream: Any, printable: bool = False) -> None:
        super().__init__(daemon=True)
        self.stream, self.printable = stream, printable
        self.lines = 0
        self.tail: list[str] = []
        self.tracebacks = 0
        self.unprintable: list[str] = []
        self.reloads: list[dict[str, Any]] = []
        """config_reloaded / config_reload_failed events, in order."""
        self.cond = threading.Condition()
        self.start()

    def run(self) -> None:
        for raw in self.stream:
            line = raw.decode("utf-8", "replace").rstrip("\n")
            with self.cond:
                self.lines += 1
                self.tail.append(line)
                del self.tail[:-50]
                if "Traceback (most recent call last)" in line:
                    self.tracebacks += 1
                if self.printable and not line.isprintable() and len(self.unprintable) < 5:
                    self.unprintable.append(line[:200])
                if line.startswith("{") and "config_reload" in line:
                    try:
                        ev = json.loads(line)
                    except ValueError:
                        ev = None
                    if isinstance(ev, dict) and ev.get("event") in RELOAD_EVENTS:
                        self.reloads.append(ev)
                self.cond.notify_all()

    def wait_reload(self, n: int, timeout: float) -> dict[str, Any] | None:
        """The reload event after the first *n*, once it comes (None after *timeout*)."""
        end = time.monotonic() + timeout
        with self.cond:
            while len(self.reloads) <= n:
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)
            return self.reloads[n]


RELOAD_EVENTS = ("config_reloaded", "config_reload_failed")


class Udp:
    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.addr = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.steps = 0
        self.stale = 0
        self.last_step = time.monotonic()

    def drain(self) -> None:
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return
            try:
                msg = json.loads(data)
            except ValueError:
                continue
            if msg.get("status") == "stale":
                self.stale += 1
            else:
                self.steps += 1
                self.last_step = time.monotonic()

    def close(self) -> None:
        self.sock.close()


SILENCE_S = 30.0
"""Longest silence (no step, no WATCHDOG=1) taken for a live daemon. Generous: at nice 10 on
a shared, loaded machine a daemon can wait seconds for a CPU; the longest gap seen is
reported either way."""


def stop_daemon(p: subprocess.Popen[bytes], res: ProcResult, timeout: float = SILENCE_S) -> None:
    """SIGTERM, then exit 0 expected within *timeout*."""
    if p.poll() is not None:
        res.dead += 1
        res.fail(f"the process had exited already, status {p.returncode}")
        res.exit(p.returncode)
        return
    res.peak_rss_mb = max(res.peak_rss_mb, hwm_mb(p.pid))
    p.send_signal(signal.SIGTERM)
    try:
        rc = p.wait(timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        rc = p.wait()
        res.fail(f"no exit within {timeout} s of SIGTERM")
    res.exit(rc)
    if rc != 0:
        res.fail(f"exit {rc} after SIGTERM")


def reap(p: subprocess.Popen[bytes], err: Lines, res: ProcResult) -> None:
    """A run's end, however it went: the process killed if it still runs and waited for, its
    stderr read to the end and its tracebacks counted."""
    if p.poll() is None:
        p.kill()
    p.wait()
    err.join(5)
    res.tracebacks += err.tracebacks


def still_publishing(p: subprocess.Popen[bytes], udp: Udp, res: ProcResult, what: str) -> None:
    """The daemon is alive and a step comes within SILENCE_S."""
    end = time.monotonic() + SILENCE_S
    n0 = udp.steps + udp.stale
    while time.monotonic() < end:
        udp.drain()
        if udp.steps + udp.stale > n0:
            return
        if p.poll() is not None:
            break
        time.sleep(0.05)
    res.dead += 1
    res.fail(
        f"{what}: no message for {SILENCE_S:g} s (process {'alive' if p.poll() is None else 'gone'})"
    )


def wait_started(p: subprocess.Popen[bytes], udp: Udp, timeout: float = 30.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        udp.drain()
        if udp.steps:
            return True
        if p.poll() is not None:
            return False
        time.sleep(0.05)
    return False
