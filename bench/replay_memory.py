#!/usr/bin/env python3
"""Replay's memory: peak RSS of ``hdrd replay`` on ordinary and hostile captures.

    python bench/replay_memory.py [--before DIR] [--workdir /tmp/hdrd-bench] [--no-write]

Takes about 30 s. Each capture is replayed by ``python -m hdrd replay CAPTURE --bias 0.1`` as a
process, its output to /dev/null; the figure is the child's peak resident set (``ru_maxrss``
from ``wait4``). ``--before DIR`` also runs the hdrd found in DIR (a checkout of an earlier
commit, e.g. ``git archive COMMIT | tar -x -C DIR``) and shows both.

The captures (made once in the work directory):

- ``mixed-1h-100hz``: the 1-hour 100 Hz capture of bench/decode.py and replay.py (5.9 MB,
  363,000 frames): the ordinary case;
- ``a55a-20mb``: 20 MB of the sync pattern ``A5 5A`` repeated: 10 million frame candidates,
  none valid;
- ``random-20mb``: 20 MB of seeded random bytes;
- ``jumps-160kb`` and ``jumps-1.6mb``: valid frames whose device clock jumps 2**31 - 1 us
  (35.8 min) per frame, so that 10,000 frames span 1.7 years of device time;
- ``clean-20mb``: 1.25 million valid frames at 1 kHz (20 min), the largest ordinary capture.

What "bounded" means here: memory follows the number of bytes and frames in the file, never
the device time it spans. Prints a table and writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import REPO, machine_line, write_section


def _jumps(n: int) -> bytes:
    from hdrd.io.wire.capture import encode_array
    from hdrd.io.wire.codec import FRAME_DTYPE

    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = np.arange(n) & 0xFFFF
    arr["t_us"] = (np.arange(n, dtype=np.int64) * (2**31 - 1)) % 2**32
    arr["rate"] = 32768
    arr["temp"] = -32768
    return encode_array(arr)


def _clean(n: int, hz: float) -> bytes:
    from hdrd.io.wire.capture import encode_array
    from hdrd.io.wire.codec import FRAME_DTYPE

    rng = np.random.default_rng(1)
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = np.arange(n) & 0xFFFF
    arr["t_us"] = (np.round(np.arange(n) * 1e6 / hz).astype(np.int64)) % 2**32
    arr["rate"] = 32768 + rng.integers(-30, 30, n)
    arr["temp"] = 2150
    return encode_array(arr)


def captures(workdir: Path) -> list[tuple[str, Path]]:
    """(name, path) of every capture, made if missing."""
    from _common import make_capture

    workdir.mkdir(parents=True, exist_ok=True)
    ordinary = workdir / "capture-1h-100hz.bin"
    make_capture(ordinary)
    made: list[tuple[str, Path]] = [("mixed-1h-100hz", ordinary)]
    for name, make in (
        ("a55a-20mb", lambda: b"\xa5\x5a" * 10_000_000),
        ("random-20mb", lambda: np.random.default_rng(7).bytes(20_000_000)),
        ("jumps-160kb", lambda: _jumps(10_000)),
        ("jumps-1.6mb", lambda: _jumps(100_000)),
        ("clean-20mb", lambda: _clean(1_250_000, 1000.0)),
    ):
        p = workdir / f"{name}.cap"
        if not p.exists():
            p.write_bytes(make())
        made.append((name, p))
    return made


def peak_rss_mb(code: Path, capture: Path) -> tuple[float, int, str]:
    """(peak RSS in MB, exit status, last stderr line) of one replay in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(code))
    p = subprocess.Popen(
        [sys.executable, "-m", "hdrd", "replay", str(capture), "--bias", "0.1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        cwd="/",
    )
    assert p.stderr is not None
    err = p.stderr.read().decode(errors="replace").strip().splitlines()
    _, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024.0, p.returncode, (err[-1] if err else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="an earlier hdrd source tree to compare")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/hdrd-bench"))
    ap.add_argument("--no-write", action="store_true", help="print only")
    args = ap.parse_args()
    trees = ([("before", args.before.resolve())] if args.before else []) + [("this tree", REPO)]
    head = "| capture | MB | " + " | ".join(f"{n}: peak RSS, MB | exit" for n, _ in trees)
    rows = []
    for name, path in captures(args.workdir):
        cells = [f"`{name}`", f"{path.stat().st_size / 1e6:.1f}"]
        for _, code in trees:
            mb, rc, last = peak_rss_mb(code, path)
            cells += [f"{mb:.0f}", str(rc)]
        rows.append("| " + " | ".join(cells) + " |")
        print(rows[-1], f"({last[:60]})" if last else "", flush=True)
    before = f"; before = {args.before}" if args.before else ""
    table = "\n".join(
        [
            f"`python bench/replay_memory.py{' --before DIR' if args.before else ''}`{before}; "
            f"{machine_line()}",
            "",
            head + " |",
            "|---|---|" + "---|---|" * len(trees),
            *rows,
        ]
    )
    print(table)
    if not args.no_write:
        write_section("speed", "Replay memory on ordinary and hostile captures", table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
