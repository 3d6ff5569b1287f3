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

import os
import pty
import select
import socket
import subprocess
import tempfile
import time
import tty
from pathlib import Path

from .procbase import (
    HDRD,
    SILENCE_S,
    Lines,
    ProcResult,
    Udp,
    hdrd_env,
    hwm_mb,
    reap,
    still_publishing,
    stop_daemon,
    wait_started,
)
from .procinput import bias_runs, capture_runs, config_sighup, config_startup
from .surfaces import generate

__all__ = ["PROCESS_SURFACES", "ProcResult", "run"]


# -- serial --------------------------------------------------------------------------------------


def _serial(seed: int, protocol: str, max_inputs: int, seconds: float) -> ProcResult:
    res = ProcResult("serial", f"hdrd run --port PTY --protocol {protocol}")
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    udp = Udp()
    t0 = time.monotonic()
    cmd = [*HDRD, "run", "--port", path, "--protocol", protocol, "--bias", "0.1", "--udp",
           udp.addr, "--log-format", "json"]  # fmt: skip
    p = subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=hdrd_env(),
    )
    res.processes = 1
    err = Lines(p.stderr)
    try:
        os.set_blocking(master, False)
        if not _clean_start(master, p, udp, protocol):
            res.fail(f"no step from clean frames: {err.tail[-3:]}")
            return res
        i = 0
        end = t0 + seconds
        while i < max_inputs and time.monotonic() < end:
            data = generate("serial", seed, i)[1:]
            _write_all(master, data, p)
            udp.drain()
            i += 1
            if p.poll() is not None:
                res.dead += 1
                res.fail(f"the daemon exited ({p.returncode}) at input {i - 1}: {err.tail[-3:]}")
                break
            if i % 500 == 0:
                res.peak_rss_mb = max(res.peak_rss_mb, hwm_mb(p.pid))
        res.inputs = i
        if p.poll() is None:
            still_publishing(p, udp, res, "after the last input")
        res.notes.append(f"{udp.steps:,} steps and {udp.stale:,} stale reports received")
        stop_daemon(p, res)
    finally:
        reap(p, err, res)
        os.close(master)
        os.close(slave)
        udp.close()
        res.seconds = time.monotonic() - t0
    return res


def _clean_start(master: int, p: subprocess.Popen[bytes], udp: Udp, protocol: str) -> bool:
    """Clean frames until the first step (at most 30 s): the daemon is past its start before
    the fuzz. Whether it stepped."""
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
    return bool(udp.steps)


def _write_all(master: int, data: bytes, p: subprocess.Popen[bytes]) -> None:
    """``data`` written to the pty as fast as the daemon reads it (until it exits)."""
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
    udp = Udp()
    t0 = time.monotonic()
    cmd = [*HDRD, "run", "--simulate", "--config", str(cfg), "--bias", "0.1", "--udp", udp.addr,
           "--gpsd", f"127.0.0.1:{port}", "--log-format", "json"]  # fmt: skip
    p = subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=hdrd_env(),
    )
    res.processes = 1
    err = Lines(p.stderr)
    longest_gap = 0.0
    try:
        if not wait_started(p, udp):
            res.fail(f"no step at start: {err.tail[-3:]}")
            return res
        i = 0
        end = t0 + seconds
        peer = _GpsdPeer(server, seed, res)
        while i < max_inputs and time.monotonic() < end and p.poll() is None:
            i, sent = peer.turn(i, udp)
            if sent:
                longest_gap = max(longest_gap, time.monotonic() - udp.last_step)
        res.inputs = i
        if p.poll() is not None:
            res.dead += 1
            res.fail(f"the daemon exited ({p.returncode}) at input {i}: {err.tail[-3:]}")
        else:
            still_publishing(p, udp, res, "after the last input")
        if longest_gap > SILENCE_S:
            res.fail(f"no step for {longest_gap:.1f} s while the peer sent")
        res.notes.append(
            f"{udp.steps:,} steps received; longest wait for a step {longest_gap:.2f} s "
            f"(a step every 0.5 s); {peer.conns} connection(s)"
        )
        if peer.conn is not None:
            peer.conn.close()
        stop_daemon(p, res)
    finally:
        reap(p, err, res)
        server.close()
        udp.close()
        res.seconds = time.monotonic() - t0
    return res


class _GpsdPeer:
    """The fuzzing gpsd: one connection at a time, VERSION first, then input after input; now
    and then it goes away."""

    def __init__(self, server: socket.socket, seed: int, res: ProcResult) -> None:
        self.server = server
        self.seed = seed
        self.res = res
        self.conn: socket.socket | None = None
        self.pending = memoryview(b"")
        self.conns = 0

    def turn(self, i: int, udp: Udp) -> tuple[int, bool]:
        """One turn: a connection accepted, or some of input ``i`` sent. The next input's
        number, and whether the turn counts for the wait for a step (it does not while no
        daemon is connected, nor when the peer goes away)."""
        if self.conn is None:
            r, _, _ = select.select([self.server], [], [], 0.5)
            udp.drain()
            if not r:
                return i, False
            self.conn, _ = self.server.accept()
            self.conn.setblocking(False)
            self.conns += 1
            self.pending = memoryview(b'{"class":"VERSION","release":"3.25","proto_major":3}\n')
        if not self.pending:
            if i and i % 5000 == 0 and self.conns < 20:  # the peer goes away now and then
                self.conn.close()
                self.conn = None
                return i + 1, False
            self.pending = memoryview(generate("gpsd", self.seed, i))
            i += 1
        self._send(i)
        udp.drain()
        return i, True

    def _send(self, i: int) -> None:
        assert self.conn is not None
        _, w, _ = select.select([], [self.conn], [], 0.2)
        if w:
            try:
                self.pending = self.pending[self.conn.send(self.pending[:65536]) :]
            except OSError:  # the daemon closed (it never should)
                self.res.fail(f"the daemon closed the gpsd connection at input {i}")
                self.conn.close()
                self.conn = None
                self.pending = memoryview(b"")


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
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=hdrd_env(),
    )
    res.processes = 1
    out, err = Lines(p.stdout, printable=True), Lines(p.stderr, printable=True)
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
        stop_daemon(p, res)
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


PROCESS_SURFACES = ("serial", "gpsd", "tail", "config", "bias", "capture")
"""The surfaces that have process-level runs (:func:`run`); the others are fuzzed in process."""


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
                config_startup(seed, per_input, workdir),
                config_sighup(seed, stream_inputs, seconds, workdir),
            ]
        if surface == "bias":
            return [bias_runs(seed, per_input, workdir)]
        if surface == "capture":
            return [capture_runs(seed, per_input, workdir)]
    raise ValueError(f"unknown surface {surface!r}")
