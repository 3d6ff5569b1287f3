#!/usr/bin/env python3
"""Start-up: ``hdrd --help``, and ``hdrd run`` from spawn to READY=1.

    python bench/startup.py [--repeats 10] [--no-write]

Takes about 20 s.

- ``hdrd --help`` as a process (the console script beside this Python), wall time from spawn
  to exit, against the interpreter alone (``python -c pass``); the hdrd modules and the heavy
  third-party ones it imports (``python -X importtime``: none, by design: ``hdrd.cli`` imports
  each subcommand's module only when it runs).
- ``hdrd run --bias 0.1`` on the fake gyro (a pty at 100 Hz), publishing to a UDP port, with
  ``NOTIFY_SOCKET`` pointing at a datagram socket bound here: time from spawn to the
  ``READY=1`` datagram. With ``--bias`` the daemon is ready once the port delivers a frame
  (at most 10 ms at 100 Hz after it opens the port), no calibration.

Target: ``hdrd --help`` <= 0.3 s. Prints the figures and
writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import hdrd_command, machine_line, ratio, time_process, write_section

HELP_TARGET_S = 0.3
HEAVY = ("numpy", "serial", "structlog", "yaml", "asyncio")


def imported(cmd_args: list[str]) -> tuple[list[str], list[str], float, float]:
    """(hdrd modules, heavy third-party modules, total import ms, ms of it in ``site``) for
    ``python -X importtime -m hdrd <args>``."""
    p = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "hdrd", *cmd_args],
        capture_output=True,
        text=True,
        check=False,
    )
    ours: list[str] = []
    heavy: list[str] = []
    total = site = 0.0
    for line in p.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        parts = line.split("|")
        name = parts[2].strip()
        if not parts[1].strip().isdigit():
            continue
        if not parts[2].startswith("  "):  # top level: cumulative time counts once
            total += int(parts[1]) / 1000
            if name == "site":
                site = int(parts[1]) / 1000
        if name.startswith("hdrd"):
            ours.append(name)
        elif name in HEAVY:
            heavy.append(name)
    return ours, heavy, total, site


def time_to_ready(repeats: int) -> list[float]:
    """Seconds from spawning ``hdrd run --bias`` to its READY=1 notification."""
    from hdrd.sim import simulate_drive
    from hdrd.sim.fakegyro import FakeGyro

    profile = simulate_drive("standstill", 2.0, 1, hz=100.0, lead_in_s=0.0)
    out: list[float] = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="hdrd-startup-") as tmp:
            notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            notify_path = os.path.join(tmp, "notify")
            notify.bind(notify_path)
            notify.settimeout(30.0)
            udp.bind(("127.0.0.1", 0))
            env = dict(os.environ, NOTIFY_SOCKET=notify_path, STATE_DIRECTORY=tmp)
            env.pop("WATCHDOG_USEC", None)
            g = FakeGyro(profile, speedup=1.0, link=os.path.join(tmp, "gyro"))
            g.start()  # writes nothing until a reader opens the port
            t0 = time.perf_counter()
            proc = subprocess.Popen(
                [
                    *hdrd_command(),
                    "run",
                    "--port",
                    os.path.join(tmp, "gyro"),
                    "--bias",
                    "0.1",
                    "--udp",
                    f"127.0.0.1:{udp.getsockname()[1]}",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=env,
            )
            try:
                while True:
                    msg = notify.recv(4096)
                    if b"READY=1" in msg.split(b"\n"):
                        out.append(time.perf_counter() - t0)
                        break
            finally:
                proc.terminate()
                proc.wait(timeout=30)
                g.close()
                notify.close()
                udp.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--no-write", action="store_true", help="print only; do not write RESULTS.md")
    a = ap.parse_args(argv)
    print(machine_line(), flush=True)
    hdrd = hdrd_command()
    help_t = time_process([*hdrd, "--help"], a.repeats)
    py_t = time_process([sys.executable, "-c", "pass"], a.repeats)
    ours, heavy, import_ms, site_ms = imported(["--help"])
    print(
        f"hdrd --help: best {help_t.best_wall:.3f} s, median {help_t.median_wall:.3f} s (python alone {py_t.best_wall:.3f} s)",
        flush=True,
    )
    ready = time_to_ready(max(3, a.repeats // 2))
    print(
        f"hdrd run to READY=1: best {min(ready):.3f} s, median {statistics.median(ready):.3f} s",
        flush=True,
    )
    how = "the console script" if len(hdrd) == 1 else "python -m hdrd"
    lines = [
        f"`python bench/startup.py --repeats {a.repeats}` on {machine_line()}.",
        "",
        f"Processes started by {how}; wall time from spawn (best and median of the runs).",
        "",
        "| | best | median | CPU | target | vs target |",
        "|---|---|---|---|---|---|",
        (
            f"| `hdrd --help` | {help_t.best_wall:.3f} s | {help_t.median_wall:.3f} s | {help_t.best_cpu:.3f} s | "
            f"<= {HELP_TARGET_S:g} s | {ratio(help_t.best_wall, HELP_TARGET_S, False)} |"
        ),
        (
            f"| `python -c pass` (the interpreter alone) | {py_t.best_wall:.3f} s | {py_t.median_wall:.3f} s | "
            f"{py_t.best_cpu:.3f} s | | |"
        ),
        (
            f"| `hdrd run --bias 0.1` to READY=1 (fake gyro, 100 Hz) | {min(ready):.3f} s | "
            f"{statistics.median(ready):.3f} s | | | |"
        ),
        "",
        (
            f"`hdrd --help` imports {', '.join(ours) or 'no hdrd module'} and, of the heavy modules "
            f"({', '.join(HEAVY)}), {', '.join(heavy) or 'none'}; {import_ms:.0f} ms of imports in all "
            f"(`python -X importtime -m hdrd --help`), {site_ms:.0f} ms of them the interpreter's own "
            "`site` (with the editable install's path hook)."
        ),
    ]
    text = "\n".join(lines)
    title = "Start-up: `hdrd --help`, and `hdrd run` to READY=1"
    write_section("speed", title, text, write=not a.no_write)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
