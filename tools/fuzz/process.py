"""Process-level fuzz runs of tools/fuzz: hdrd as it runs, fed the fuzzed inputs.

Where a surface is reached through a process, these runs hand it the inputs of
tools/fuzz/inputs.py the way the world does, and check what the process does:

- ``serial``: ``hdrd run --port PTY`` with the inputs written to the pty as fast as it
  reads them (hdr-bin, then hdr-text);
- ``gpsd``: ``hdrd run --simulate --gpsd`` against a peer that plays gpsd: VERSION, then the
  inputs as fast as the socket takes them, now and then closing the connection;
- ``tail``: ``hdrd tail`` (table, then ``--raw``) sent the inputs as UDP datagrams;
- ``config``: ``hdrd run --simulate --config FILE`` started on inputs, and one daemon
  reloaded (SIGHUP) with input after input;
- ``bias``: ``hdrd run --simulate`` with the input as its bias file (``on_bad_bias_file``
  error and calibrate), and ``hdrd replay --bias-file``;
- ``capture``: ``hdrd replay`` and ``hdrd convert`` on inputs.

Checks: no ``Traceback`` on stderr; a long-running daemon alive after every input and still
publishing (steps over UDP, or for the reload run ``WATCHDOG=1`` on a ``NOTIFY_SOCKET``:
the daemon pings only after progress), exit 0 on SIGTERM; a process per input exits with a
documented status, and a refusal says so in one line (structured log lines aside); a SIGHUP
is answered by ``config_reloaded`` or ``config_reload_failed``. Peak RSS: ``VmHWM`` of a
long-running daemon, ``ru_maxrss`` (os.wait4) of a process per input.
"""

from __future__ import annotations

import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .surfaces import generate

REPO = Path(__file__).resolve().parents[2]

__all__ = ["ProcResult", "run"]


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


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("NOTIFY_SOCKET", None)
    env.pop("WATCHDOG_USEC", None)
    env.update(extra)
    return env


HDRD = [sys.executable, "-m", "hdrd"]


def _hwm_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


class _Lines(threading.Thread):
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


class _Udp:
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


def _stop(p: subprocess.Popen[bytes], res: ProcResult, timeout: float = SILENCE_S) -> None:
    """SIGTERM, then exit 0 expected within *timeout*."""
    if p.poll() is not None:
        res.dead += 1
        res.fail(f"the process had exited already, status {p.returncode}")
        res.exit(p.returncode)
        return
    res.peak_rss_mb = max(res.peak_rss_mb, _hwm_mb(p.pid))
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


def _still_publishing(p: subprocess.Popen[bytes], udp: _Udp, res: ProcResult, what: str) -> None:
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


def _wait_started(p: subprocess.Popen[bytes], udp: _Udp, timeout: float = 30.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        udp.drain()
        if udp.steps:
            return True
        if p.poll() is not None:
            return False
        time.sleep(0.05)
    return False


# -- serial --------------------------------------------------------------------------------------


def _serial(seed: int, protocol: str, max_inputs: int, seconds: float) -> ProcResult:
    res = ProcResult("serial", f"hdrd run --port PTY --protocol {protocol}")
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    udp = _Udp()
    t0 = time.monotonic()
    p = subprocess.Popen(
        [
            *HDRD,
            "run",
            "--port",
            path,
            "--protocol",
            protocol,
            "--bias",
            "0.1",
            "--udp",
            udp.addr,
            "--log-format",
            "json",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=_env(),
    )
    res.processes = 1
    err = _Lines(p.stderr)
    try:
        os.set_blocking(master, False)
        # clean frames until the first step: the daemon is past its start before the fuzz
        from hdrd.io.wire.codec import Frame, encode

        k = 0
        deadline = time.monotonic() + 30.0
        while not udp.steps and p.poll() is None and time.monotonic() < deadline:
            clean = b"".join(
                encode(Frame(j & 0xFFFF, j * 10_000, 32768, 0, None), protocol)
                for j in range(k, k + 20)
            )
            k += 20
            try:
                os.write(master, clean)
            except BlockingIOError:
                pass
            time.sleep(0.02)
            udp.drain()
        if not udp.steps:
            res.fail(f"no step from clean frames: {err.tail[-3:]}")
            return res
        i = 0
        end = t0 + seconds
        while i < max_inputs and time.monotonic() < end:
            data = generate("serial", seed, i)[1:]
            view = memoryview(data)
            while view:
                _, w, _ = select.select([], [master], [], 1.0)
                if w:
                    try:
                        n = os.write(master, view[:4096])
                    except BlockingIOError:
                        n = 0
                    view = view[n:]
                try:
                    os.read(master, 65536)  # whatever the line discipline echoes
                except (BlockingIOError, OSError):
                    pass
                if p.poll() is not None:
                    break
            udp.drain()
            i += 1
            if p.poll() is not None:
                res.dead += 1
                res.fail(f"the daemon exited ({p.returncode}) at input {i - 1}: {err.tail[-3:]}")
                break
            if i % 500 == 0:
                res.peak_rss_mb = max(res.peak_rss_mb, _hwm_mb(p.pid))
        res.inputs = i
        if p.poll() is None:
            _still_publishing(p, udp, res, "after the last input")
        res.notes.append(f"{udp.steps:,} steps and {udp.stale:,} stale reports received")
        _stop(p, res)
    finally:
        if p.poll() is None:
            p.kill()
        p.wait()
        err.join(5)
        res.tracebacks += err.tracebacks
        os.close(master)
        os.close(slave)
        udp.close()
        res.seconds = time.monotonic() - t0
    return res


# -- gpsd ----------------------------------------------------------------------------------------


GPSD_DRIVE = "simulate:\n  rate_hz: 250\n  speedup: 2\n"
"""The simulated gyro of the gpsd run: 500 frames (loop turns, gpsd polls) per second, a step
every 0.5 s, and the 20-minute drive lasts 10 minutes."""


def _gpsd(seed: int, max_inputs: int, seconds: float, workdir: Path) -> ProcResult:
    res = ProcResult("gpsd", "hdrd run --simulate --gpsd (a fuzzing gpsd peer)")
    seconds = min(seconds, 560.0)  # before the simulated drive ends
    cfg = workdir / "gpsd-run.yaml"
    cfg.write_text(GPSD_DRIVE)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    udp = _Udp()
    t0 = time.monotonic()
    p = subprocess.Popen(
        [
            *HDRD,
            "run",
            "--simulate",
            "--config",
            str(cfg),
            "--bias",
            "0.1",
            "--udp",
            udp.addr,
            "--gpsd",
            f"127.0.0.1:{port}",
            "--log-format",
            "json",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=_env(),
    )
    res.processes = 1
    err = _Lines(p.stderr)
    conns = 0
    longest_gap = 0.0
    try:
        if not _wait_started(p, udp):
            res.fail(f"no step at start: {err.tail[-3:]}")
            return res
        i = 0
        end = t0 + seconds
        conn: socket.socket | None = None
        pending = memoryview(b"")
        while i < max_inputs and time.monotonic() < end and p.poll() is None:
            if conn is None:
                r, _, _ = select.select([server], [], [], 0.5)
                udp.drain()
                if not r:
                    continue
                conn, _ = server.accept()
                conn.setblocking(False)
                conns += 1
                pending = memoryview(b'{"class":"VERSION","release":"3.25","proto_major":3}\n')
            if not pending:
                if i and i % 5000 == 0 and conns < 20:  # the peer goes away now and then
                    conn.close()
                    conn = None
                    i += 1
                    continue
                pending = memoryview(generate("gpsd", seed, i))
                i += 1
            _, w, _ = select.select([], [conn], [], 0.2)
            if w:
                try:
                    pending = pending[conn.send(pending[:65536]) :]
                except OSError:  # the daemon closed (it never should)
                    res.fail(f"the daemon closed the gpsd connection at input {i}")
                    conn.close()
                    conn = None
                    pending = memoryview(b"")
            udp.drain()
            longest_gap = max(longest_gap, time.monotonic() - udp.last_step)
        res.inputs = i
        if p.poll() is not None:
            res.dead += 1
            res.fail(f"the daemon exited ({p.returncode}) at input {i}: {err.tail[-3:]}")
        else:
            _still_publishing(p, udp, res, "after the last input")
        if longest_gap > SILENCE_S:
            res.fail(f"no step for {longest_gap:.1f} s while the peer sent")
        res.notes.append(
            f"{udp.steps:,} steps received; longest wait for a step {longest_gap:.2f} s "
            f"(a step every 0.5 s); {conns} connection(s)"
        )
        if conn is not None:
            conn.close()
        _stop(p, res)
    finally:
        if p.poll() is None:
            p.kill()
        p.wait()
        err.join(5)
        res.tracebacks += err.tracebacks
        server.close()
        udp.close()
        res.seconds = time.monotonic() - t0
    return res


# -- tail ----------------------------------------------------------------------------------------


def _tail(seed: int, raw: bool, max_inputs: int, seconds: float) -> ProcResult:
    res = ProcResult("tail", "hdrd tail" + (" --raw" if raw else ""))
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    t0 = time.monotonic()
    cmd = [*HDRD, "tail", "--listen", f"127.0.0.1:{port}"] + (["--raw"] if raw else [])
    p = subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env()
    )
    res.processes = 1
    out, err = _Lines(p.stdout, printable=True), _Lines(p.stderr, printable=True)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        time.sleep(1.0)  # its start-up: imports, bind
        i = 0
        end = t0 + seconds
        while i < max_inputs and time.monotonic() < end and p.poll() is None:
            data = generate("tail", seed, i)
            try:
                s.sendto(data, ("127.0.0.1", port))
            except OSError as e:
                res.notes.append(f"send of input {i} failed: {e}") if len(res.notes) < 3 else None
            i += 1
            if i % 50 == 0:
                time.sleep(0.01)  # let it keep up (a datagram dropped is an input not tested)
        res.inputs = i
        time.sleep(0.5)
        if p.poll() is not None:
            res.dead += 1
            res.fail(f"hdrd tail exited ({p.returncode}) at input {i}: {err.tail[-3:]}")
        _stop(p, res)
    finally:
        if p.poll() is None:
            p.kill()
        p.wait()
        out.join(5)
        err.join(5)
        s.close()
        res.tracebacks += out.tracebacks + err.tracebacks
        for what, lines in (("stdout", out), ("stderr", err)):
            for line in lines.unprintable:
                res.fail(f"{what} line not printable: {line!r}")
        res.notes.append(f"{out.lines:,} lines on stdout, {err.lines:,} notes on stderr")
        res.seconds = time.monotonic() - t0
    return res


# -- processes per input ---------------------------------------------------------------------------


def _plain_lines(stderr: bytes) -> list[str]:
    """stderr's lines that are not structured log lines (JSON objects with an event)."""
    out = []
    for line in stderr.decode("utf-8", "replace").splitlines():
        if line.startswith("{"):
            try:
                if "event" in json.loads(line):
                    continue
            except ValueError:
                pass
        out.append(line)
    return out


def _run_once(
    cmd: list[str], res: ProcResult, stop_after: float | None, timeout: float = 60.0
) -> tuple[int, list[str]]:
    """Run *cmd*; with *stop_after*, a process still running then gets SIGTERM (and must exit
    0). Returns (status, stderr's plain lines); counts tracebacks and peak RSS."""
    with tempfile.TemporaryFile() as errf:
        p = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=errf, env=_env()
        )
        res.processes += 1
        deadline = time.monotonic() + (stop_after if stop_after is not None else timeout)
        signalled = False
        while True:
            pid, status, ru = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                if signalled:
                    p.kill()
                    _, status, ru = os.wait4(p.pid, 0)
                    res.fail(f"no exit within 10 s of SIGTERM: {cmd[3:]}")
                    break
                if stop_after is None:
                    res.fail(f"still running after {timeout} s: {cmd[3:]}")
                p.send_signal(signal.SIGTERM)
                signalled = True
                deadline = time.monotonic() + 10.0
            time.sleep(0.02)
        p.returncode = os.waitstatus_to_exitcode(status)
        res.peak_rss_mb = max(res.peak_rss_mb, ru.ru_maxrss / 1024)
        errf.seek(0)
        stderr = errf.read()
    if b"Traceback (most recent call last)" in stderr:
        res.tracebacks += 1
        res.fail(f"traceback: {cmd[3:]}: {stderr.decode('utf-8', 'replace')[-300:]}")
    res.exit(p.returncode)
    return p.returncode, _plain_lines(stderr)


def _one_line(res: ProcResult, lines: list[str], prefix: str, what: str) -> None:
    if len(lines) != 1 or not lines[0].startswith(prefix) or not lines[0].isprintable():
        res.fail(f"{what}: expected one line starting {prefix!r}, got {lines[:3]!r}")


def _config_startup(seed: int, n: int, workdir: Path) -> ProcResult:
    res = ProcResult("config", "hdrd run --simulate --config INPUT")
    t0 = time.monotonic()
    path = workdir / "hdrd.yaml"
    udp = _Udp()
    try:
        for i in range(n):
            path.write_bytes(generate("config", seed, i))
            rc, lines = _run_once(
                [
                    *HDRD,
                    "run",
                    "--simulate",
                    "--speedup",
                    "20",
                    "--bias",
                    "0.1",
                    "--config",
                    str(path),
                    "--udp",
                    udp.addr,
                    "--log-format",
                    "json",
                ],
                res,
                stop_after=2.0,
            )
            res.inputs += 1
            if rc == 78:
                _one_line(res, lines, "hdrd: config error", f"input {i}")
            elif rc != 0:
                res.fail(f"input {i}: exit {rc}: {lines[-3:]}")
            udp.drain()
    finally:
        udp.close()
    res.seconds = time.monotonic() - t0
    return res


def _config_sighup(seed: int, max_inputs: int, seconds: float, workdir: Path) -> ProcResult:
    res = ProcResult("config", "SIGHUP: one daemon reloaded with input after input")
    path = workdir / "reload.yaml"
    path.write_text("hdr:\n  method: hdr\n")
    notify_path = workdir / "notify.sock"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(notify_path))
    notify.setblocking(False)
    t0 = time.monotonic()
    p = subprocess.Popen(
        [
            *HDRD,
            "run",
            "--simulate",
            "--speedup",
            "10",
            "--bias",
            "0.1",
            "--config",
            str(path),
            "--log-format",
            "json",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=_env(NOTIFY_SOCKET=str(notify_path), WATCHDOG_USEC="1000000"),
    )
    res.processes = 1
    err = _Lines(p.stderr)
    pings = 0
    last_ping = time.monotonic()
    longest = 0.0
    outcomes: Counter[str] = Counter()

    def read_pings() -> None:
        nonlocal pings, last_ping, longest
        while True:
            try:
                msg = notify.recv(4096)
            except BlockingIOError:
                return
            if b"WATCHDOG=1" in msg:
                now = time.monotonic()
                longest = max(longest, now - last_ping)
                pings += 1
                last_ping = now

    try:
        # READY=1 first
        end = time.monotonic() + 30
        while pings == 0 and time.monotonic() < end and p.poll() is None:
            read_pings()
            time.sleep(0.05)
        last_ping = time.monotonic()
        i = 0
        end = t0 + seconds
        while i < max_inputs and time.monotonic() < end and p.poll() is None:
            tmp = path.with_suffix(".tmp")
            tmp.write_bytes(generate("config", seed, i))
            os.replace(tmp, path)
            n = len(err.reloads)
            p.send_signal(signal.SIGHUP)
            ev = err.wait_reload(n, SILENCE_S)
            i += 1
            read_pings()
            if ev is None:
                res.fail(f"no answer to SIGHUP at input {i - 1}: {err.tail[-3:]}")
                if p.poll() is not None:
                    break
                continue
            outcomes[ev["event"]] += 1
            if ev["event"] == "config_reload_failed":
                e = str(ev.get("error", ""))
                if "\n" in e or not e.isprintable():
                    res.fail(f"input {i - 1}: config_reload_failed error not one line: {e[:200]!r}")
        res.inputs = i
        if p.poll() is not None:
            res.dead += 1
            res.fail(f"the daemon exited ({p.returncode}) at input {i}: {err.tail[-3:]}")
        else:
            end = time.monotonic() + SILENCE_S
            n0 = pings
            while time.monotonic() < end and pings == n0:
                read_pings()
                time.sleep(0.05)
            if pings == n0:
                res.dead += 1
                res.fail(f"no WATCHDOG=1 for {SILENCE_S:g} s after the last reload")
        if longest > SILENCE_S:
            res.fail(f"WATCHDOG=1 stopped for {longest:.1f} s during the reloads")
        res.notes.append(
            f"answers: {dict(outcomes)}; {pings:,} WATCHDOG=1 received, longest gap {longest:.2f} s"
        )
        _stop(p, res)
    finally:
        if p.poll() is None:
            p.kill()
        p.wait()
        err.join(5)
        res.tracebacks += err.tracebacks
        notify.close()
        res.seconds = time.monotonic() - t0
    return res


def _bias(seed: int, n: int, workdir: Path) -> ProcResult:
    res = ProcResult(
        "bias", "hdrd run --simulate with the input as bias file; hdrd replay --bias-file"
    )
    t0 = time.monotonic()
    bias = workdir / "bias.yaml"
    cap = workdir / "ok.bin"
    from hdrd.io.wire.codec import Frame, encode_bin

    cap.write_bytes(b"".join(encode_bin(Frame(i, i * 100_000, 32768, 0, None)) for i in range(50)))
    udp = _Udp()
    try:
        for i in range(n):
            bias.write_bytes(generate("bias", seed, i))
            mode = ("error", "calibrate")[i % 2]
            cfg = workdir / "cfg.yaml"
            cfg.write_text(
                f"calibration:\n  bias_file: {json.dumps(str(bias))}\n  on_bad_bias_file: {mode}\n"
            )
            rc, lines = _run_once(
                [
                    *HDRD,
                    "run",
                    "--simulate",
                    "--speedup",
                    "20",
                    "--config",
                    str(cfg),
                    "--udp",
                    udp.addr,
                    "--log-format",
                    "json",
                ],
                res,
                stop_after=2.0,
            )
            if rc == 1 and mode == "error":
                _one_line(res, lines, "hdrd: bias file", f"run, input {i}")
            elif rc != 0:
                res.fail(f"run, input {i} ({mode}): exit {rc}: {lines[-3:]}")
            rc, lines = _run_once(
                [*HDRD, "replay", "--bias-file", str(bias), str(cap)], res, stop_after=None
            )
            if rc == 1:
                _one_line(res, lines, "hdrd replay: bias file", f"replay, input {i}")
            elif rc != 0:
                res.fail(f"replay, input {i}: exit {rc}: {lines[-3:]}")
            res.inputs += 1
            udp.drain()
    finally:
        udp.close()
    res.seconds = time.monotonic() - t0
    return res


def _capture(seed: int, n: int, workdir: Path) -> ProcResult:
    res = ProcResult("capture", "hdrd replay and hdrd convert on the input")
    t0 = time.monotonic()
    cap = workdir / "capture.bin"
    for i in range(n):
        data = generate("capture", seed, i)
        protocol = "hdr-bin" if data[:1] == b"B" else "hdr-text"
        cap.write_bytes(data[1:])
        rc, lines = _run_once(
            [*HDRD, "replay", "--protocol", protocol, "--bias", "0.1", str(cap)], res, None
        )
        if rc == 1:
            _one_line(res, lines, "hdrd replay: no valid frames", f"replay, input {i}")
        elif rc != 0 or lines:
            res.fail(f"replay, input {i}: exit {rc}: {lines[-3:]}")
        rc2, lines = _run_once(
            [*HDRD, "convert", "--protocol", protocol, str(cap), "--out", str(workdir / "x.csv")],
            res,
            None,
        )
        if rc2 != rc:
            res.fail(f"convert, input {i}: exit {rc2}, replay {rc}")
        _one_line(res, lines, "hdrd convert: no valid frames" if rc2 else "", f"convert, input {i}")
        res.inputs += 1
    res.seconds = time.monotonic() - t0
    return res


def run(
    surface: str, seed: int, per_input: int, seconds: float, stream_inputs: int = 100_000
) -> list[ProcResult]:
    """The process-level runs of *surface*: *per_input* inputs where each starts a process,
    at most *stream_inputs* inputs and *seconds* s against one long-running process."""
    with tempfile.TemporaryDirectory(prefix=f"hdrd-fuzzp-{surface}-") as d:
        workdir = Path(d)
        if surface == "serial":
            return [_serial(seed, pr, stream_inputs, seconds) for pr in ("hdr-bin", "hdr-text")]
        if surface == "gpsd":
            return [_gpsd(seed, stream_inputs, seconds, workdir)]
        if surface == "tail":
            return [_tail(seed, raw, stream_inputs, seconds / 2) for raw in (False, True)]
        if surface == "config":
            return [
                _config_startup(seed, per_input, workdir),
                _config_sighup(seed, stream_inputs, seconds, workdir),
            ]
        if surface == "bias":
            return [_bias(seed, per_input, workdir)]
        if surface == "capture":
            return [_capture(seed, per_input, workdir)]
    raise ValueError(f"unknown surface {surface!r}")
