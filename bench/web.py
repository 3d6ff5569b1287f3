#!/usr/bin/env python3
"""``hdrd web`` with viewers: its CPU and memory while it pushes the daemon's steps.

    python bench/web.py [--clients 10] [--minutes 10] [--rate-hz 1] [--no-write]

Takes ``--minutes`` (10 by default) plus a few seconds.

``hdrd web`` runs as a user runs it (the console script), on loopback ports; ``--clients``
viewers hold its event stream open (plain sockets, read as fast as they come, as a browser
does), and a sender plays the daemon: one HDR message at ``--rate-hz`` with every key a GPS-
aided step has (~370 bytes). Measured over the run, after a 5 s warm-up: the CPU share of one
core (user + system, ``/proc/<pid>/stat``), the resident memory (``VmRSS`` every 10 s, and
``VmHWM``, the peak), and the time from a datagram's send to its event's arrival at each
viewer (p50, p99, max). Every viewer must get every message (checked). Prints the figures and
replaces its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import json
import os
import selectors
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import fmt, hdrd_command, machine_line, put_section

HEADING = "## hdrd web with viewers"
WARMUP_S = 5.0


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def message(step: int, now: float) -> bytes:
    """A GPS-aided step as the daemon sends it (its keys, typical values)."""
    msg = {
        "class": "HDR", "v": 1, "time": now, "t": float(step), "step": step,
        "omega_raw": 0.3121, "omega": 0.0702, "yaw": -3.42, "heading": (93.42 + step) % 360,
        "I": -0.0844, "W": 1, "R": 0.538, "r": 3, "bias": 0.2419, "samples": 10,
        "bad_frames": 0, "status": "ok", "temp": 24.5, "bias_source": "gps",
        "calib_age_s": 1234.5, "frames": 10 * step, "reconnects": 0, "mode": "aided",
        "heading_offset": 1.25, "gps_course": 93.1, "gps_age_s": 0.4, "gps_speed": 14.2,
    }  # fmt: skip
    return (json.dumps(msg, separators=(",", ":")) + "\n").encode()


class Viewers:
    """``n`` open streams read by one thread; for each message (by step), when it arrived."""

    def __init__(self, port: int, n: int) -> None:
        self.sel = selectors.DefaultSelector()
        self.arrived: dict[int, list[float]] = {}
        self.bufs: dict[socket.socket, bytes] = {}
        for _ in range(n):
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            s.setblocking(False)
            self.sel.register(s, selectors.EVENT_READ)
            self.bufs[s] = b""
        self.running = True
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        while self.running:
            for key, _ in self.sel.select(0.2):
                s: Any = key.fileobj
                chunk = s.recv(65536)
                if not chunk:
                    raise SystemExit("hdrd web closed a viewer's stream")
                now = time.monotonic()
                buf = self.bufs[s] + chunk
                *events, self.bufs[s] = buf.split(b"\n\n")
                for e in events:
                    if e.startswith(b"event: msg\n"):
                        step = json.loads(e.split(b"data: ", 1)[1])["msg"]["step"]
                        self.arrived.setdefault(step, []).append(now)

    def close(self) -> None:
        self.running = False
        self.thread.join(5)
        for s in self.bufs:
            s.close()


def proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def run(clients: int, minutes: float, rate_hz: float) -> dict[str, Any]:
    """Long because it is one measurement, start to end, read best in one place."""
    port, uport = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
    cmd = [*hdrd_command(), "web", "--listen", f"127.0.0.1:{port}", "--udp", f"127.0.0.1:{uport}"]
    cmd += ["--max-clients", str(max(clients, 16))]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    while "hdrd web: open" not in (line := proc.stderr.readline()):
        if not line:
            raise SystemExit("hdrd web did not start")
    viewers = Viewers(port, clients)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent: dict[int, float] = {}
    rss: list[int] = []
    t_start = time.monotonic()
    t_end = t_start + WARMUP_S + 60.0 * minutes
    cpu0 = None
    step = 0
    next_rss = t_start + WARMUP_S
    while (now := time.monotonic()) < t_end:
        if cpu0 is None and now >= t_start + WARMUP_S:
            cpu0, w0 = proc_cpu_s(proc.pid), now
        if now >= next_rss:
            rss.append(proc_kb(proc.pid, "VmRSS"))
            next_rss += 10.0
        sent[step] = time.monotonic()
        sender.sendto(message(step, time.time()), ("127.0.0.1", uport))
        step += 1
        time.sleep(max(0.0, t_start + step / rate_hz - time.monotonic()))
    time.sleep(1.0)  # the last events arrive
    assert cpu0 is not None
    cpu = proc_cpu_s(proc.pid) - cpu0
    wall = time.monotonic() - w0
    hwm = proc_kb(proc.pid, "VmHWM")
    viewers.close()
    sender.close()
    proc.terminate()
    proc.wait(10)
    missing = sum(clients - len(viewers.arrived.get(k, [])) for k in sent)
    lat = sorted(t - sent[k] for k, ts in viewers.arrived.items() for t in ts)
    return {
        "messages": len(sent),
        "missing": missing,
        "cpu_share": cpu / wall,
        "cpu_s": cpu,
        "wall_s": wall,
        "rss_mb": [r / 1024 for r in rss],
        "hwm_mb": hwm / 1024,
        "lat_ms": [
            1000 * lat[len(lat) // 2],
            1000 * lat[int(0.99 * (len(lat) - 1))],
            1000 * lat[-1],
        ],
        "cmd": cmd,
    }


def report(r: dict[str, Any], args: argparse.Namespace, machine: str) -> str:
    shown = f"python bench/web.py --clients {args.clients} --minutes {args.minutes:g}"
    if args.rate_hz != 1.0:
        shown += f" --rate-hz {args.rate_hz:g}"
    rss = r["rss_mb"]
    p50, p99, worst = r["lat_ms"]
    return (
        f"{HEADING}\n\n`{shown}` on {machine}.\n\n"
        f"`hdrd web` as a process (`hdrd web --listen 127.0.0.1:P --udp 127.0.0.1:U`), "
        f"{args.clients} viewers on its event stream, one HDR message ({len(message(0, 0.0))} "
        f"bytes, a GPS-aided step) at {args.rate_hz:g} Hz for {args.minutes:g} min "
        f"({r['messages']} messages; every viewer got every one: {r['missing']} missing).\n\n"
        "| | figure |\n|---|---|\n"
        f"| CPU, share of one core | {100 * r['cpu_share']:.2f} % ({fmt(r['cpu_s'], 2)} s "
        f"in {fmt(r['wall_s'], 0)} s) |\n"
        f"| resident memory (VmRSS, every 10 s) | {min(rss):.1f} - {max(rss):.1f} MB, "
        f"at the end {rss[-1]:.1f} MB |\n"
        f"| peak resident memory (VmHWM) | {r['hwm_mb']:.1f} MB |\n"
        f"| datagram sent to event read by a viewer (p50 / p99 / max) | {p50:.2f} / "
        f"{p99:.2f} / {worst:.2f} ms |\n"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate-hz", type=float, default=1.0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    machine = machine_line()
    r = run(args.clients, args.minutes, args.rate_hz)
    text = report(r, args, machine)
    print(text)
    if r["missing"]:
        raise SystemExit(f"{r['missing']} events did not reach their viewer")
    if not args.no_write:
        put_section("speed", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
