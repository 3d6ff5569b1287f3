"""Process-level fuzz runs of tools/fuzz that start a process per input (tools/fuzz/process.py
says what each run feeds and checks): ``hdrd run --config`` at start-up and one daemon reloaded
(SIGHUP) input after input, ``hdrd run`` and ``hdrd replay`` with the input as their bias file,
``hdrd replay`` and ``hdrd convert`` on captures."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import tempfile
import time
from collections import Counter
from pathlib import Path

from .procbase import HDRD, SILENCE_S, Lines, ProcResult, Udp, hdrd_env, reap, stop_daemon
from .surfaces import generate

__all__ = ["bias_runs", "capture_runs", "config_sighup", "config_startup"]


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
            cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=errf, env=hdrd_env()
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


def config_startup(seed: int, n: int, workdir: Path) -> ProcResult:
    res = ProcResult("config", "hdrd run --simulate --config INPUT")
    t0 = time.monotonic()
    path = workdir / "hdrd.yaml"
    udp = Udp()
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


class _Watchdog:
    """The daemon's ``WATCHDOG=1`` pings on a NOTIFY_SOCKET: how many, and the longest gap (s)."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.setblocking(False)
        self.pings = 0
        self.last_ping = time.monotonic()
        self.longest = 0.0

    def read(self) -> None:
        while True:
            try:
                msg = self.sock.recv(4096)
            except BlockingIOError:
                return
            if b"WATCHDOG=1" in msg:
                now = time.monotonic()
                self.longest = max(self.longest, now - self.last_ping)
                self.pings += 1
                self.last_ping = now

    def wait_ping(self, timeout: float, p: subprocess.Popen[bytes]) -> bool:
        """Whether a ping came within ``timeout`` s (while the daemon runs)."""
        n0 = self.pings
        end = time.monotonic() + timeout
        while self.pings == n0 and time.monotonic() < end and p.poll() is None:
            self.read()
            time.sleep(0.05)
        return self.pings != n0

    def close(self) -> None:
        self.sock.close()


def _reload(
    p: subprocess.Popen[bytes], err: Lines, path: Path, data: bytes, i: int, res: ProcResult
) -> str | None:
    """Input ``i`` as the configuration, and SIGHUP: the daemon's answer (None: none, a
    failure noted), its error checked to be one line."""
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)
    n = len(err.reloads)
    p.send_signal(signal.SIGHUP)
    ev = err.wait_reload(n, SILENCE_S)
    if ev is None:
        res.fail(f"no answer to SIGHUP at input {i}: {err.tail[-3:]}")
        return None
    if ev["event"] == "config_reload_failed":
        e = str(ev.get("error", ""))
        if "\n" in e or not e.isprintable():
            res.fail(f"input {i}: config_reload_failed error not one line: {e[:200]!r}")
    return str(ev["event"])


def config_sighup(seed: int, max_inputs: int, seconds: float, workdir: Path) -> ProcResult:
    res = ProcResult("config", "SIGHUP: one daemon reloaded with input after input")
    path = workdir / "reload.yaml"
    path.write_text("hdr:\n  method: hdr\n")
    notify_path = workdir / "notify.sock"
    dog = _Watchdog(notify_path)
    t0 = time.monotonic()
    cmd = [*HDRD, "run", "--simulate", "--speedup", "10", "--bias", "0.1", "--config",
           str(path), "--log-format", "json"]  # fmt: skip
    p = subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=hdrd_env(NOTIFY_SOCKET=str(notify_path), WATCHDOG_USEC="1000000"),
    )
    res.processes = 1
    err = Lines(p.stderr)
    outcomes: Counter[str] = Counter()
    try:
        dog.wait_ping(30, p)  # READY=1 first
        dog.last_ping = time.monotonic()
        i = 0
        end = t0 + seconds
        while i < max_inputs and time.monotonic() < end and p.poll() is None:
            answer = _reload(p, err, path, generate("config", seed, i), i, res)
            i += 1
            dog.read()
            if answer is not None:
                outcomes[answer] += 1
        res.inputs = i
        if p.poll() is not None:
            res.dead += 1
            res.fail(f"the daemon exited ({p.returncode}) at input {i}: {err.tail[-3:]}")
        elif not dog.wait_ping(SILENCE_S, p):
            res.dead += 1
            res.fail(f"no WATCHDOG=1 for {SILENCE_S:g} s after the last reload")
        if dog.longest > SILENCE_S:
            res.fail(f"WATCHDOG=1 stopped for {dog.longest:.1f} s during the reloads")
        res.notes.append(
            f"answers: {dict(outcomes)}; {dog.pings:,} WATCHDOG=1 received, longest gap "
            f"{dog.longest:.2f} s"
        )
        stop_daemon(p, res)
    finally:
        reap(p, err, res)
        dog.close()
        res.seconds = time.monotonic() - t0
    return res


def bias_runs(seed: int, n: int, workdir: Path) -> ProcResult:
    res = ProcResult(
        "bias", "hdrd run --simulate with the input as bias file; hdrd replay --bias-file"
    )
    t0 = time.monotonic()
    bias = workdir / "bias.yaml"
    cap = workdir / "ok.bin"
    from hdrd.io.wire.codec import Frame, encode_bin

    cap.write_bytes(b"".join(encode_bin(Frame(i, i * 100_000, 32768, 0, None)) for i in range(50)))
    udp = Udp()
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


def capture_runs(seed: int, n: int, workdir: Path) -> ProcResult:
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
