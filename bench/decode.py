#!/usr/bin/env python3
"""Decode: frames per second of the push parser and of the vectorised capture decoder.

    python bench/decode.py [--repeats 5] [--workdir /tmp/hdrd-bench] [--no-write]

Takes about 30 s (the first run also writes the capture, ~3 s). The capture is a 1-hour
simulated drive at 100 Hz (``bench/_common.py``: 363,000 frames, 1 % of the bytes garbage,
0.1 % of the frames with a CRC error). Measured in this process:

- **push parser** (:class:`hdrd.io.wire.parser.Parser`, what ``hdrd run`` runs): the capture fed in
  chunks of 64 bytes (cut beforehand, not timed), then flushed;
- **vectorised decoder** (:func:`hdrd.io.wire.capture.decode_capture`, what ``hdrd replay`` runs): the
  whole capture at once; its first call in the process is reported apart (fresh memory).

Both give the same frames and counters (checked here too). Figures: best of ``--repeats`` runs,
wall clock and CPU time (``time.process_time``), against the targets (push >= 500,000
frames/s, vectorised >= 5,000,000) and the wire's limit (a 3 Mbaud link carries at most 18,750
hdr-bin frames/s). Prints them and writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import (
    WIRE_FRAMES_PER_S,
    capture_bench_setup,
    capture_line,
    machine_line,
    ratio,
    time_in_process,
    write_section,
)

from hdrd.io.wire.capture import decode_capture
from hdrd.io.wire.codec import array_to_frames
from hdrd.io.wire.parser import Parser

PUSH_TARGET = 500_000
VECTOR_TARGET = 5_000_000
CHUNK = 64


def _lines(
    repeats: int,
    meta: dict[str, Any],
    n: int,
    rows: list[tuple[str, Any, int]],
    first_cpu: float,
    bad_frames: int,
    same: bool,
) -> list[str]:
    """The section's lines: the command, the capture, each decoder's rate (frames/s) against
    its target and the wire, the first call's, and whether the two decoders agree (each
    decoder's rate printed too)."""
    lines = [
        f"`python bench/decode.py --repeats {repeats}` on {machine_line()}.",
        "",
        (
            f"Capture: {capture_line(meta)}. Best of the runs, in this process; frames/s from wall "
            "clock (and from CPU time); ratios > 1 are inside the target. The wire's limit: a 3 Mbaud "
            f"link carries at most {WIRE_FRAMES_PER_S:,.0f} hdr-bin frames/s."
        ),
        "",
        "| decoder | best wall | frames/s (wall) | frames/s (CPU) | target | vs target | vs wire |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, t, target in rows:
        fps_wall = n / t.best_wall
        fps_cpu = n / t.best_cpu
        lines.append(
            f"| {name} | {t.best_wall * 1e3:.0f} ms | {fps_wall:,.0f} | {fps_cpu:,.0f} | "
            f">= {target:,} | {ratio(fps_wall, target, True)} | {fps_wall / WIRE_FRAMES_PER_S:,.0f}x |"
        )
        print(
            f"{name}: {fps_wall:,.0f} frames/s wall, {fps_cpu:,.0f} CPU ({t.best_wall * 1e3:.1f} ms best)",
            flush=True,
        )
    lines += [
        "",
        (
            f"The vectorised decoder's first call in a process (fresh memory, as in `hdrd replay`): "
            f"{first_cpu * 1e3:.0f} ms CPU, {n / first_cpu:,.0f} frames/s. Frames decoded: {n:,}; bad frames "
            f"{bad_frames:,}; push parser == vectorised (frames and every counter): {'yes' if same else 'NO'}."
        ),
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    a, cap, meta = capture_bench_setup(__doc__, argv)
    data = cap.read_bytes()

    t0 = time.process_time()
    arr, cst = decode_capture(data)
    first_cpu = time.process_time() - t0
    vec, _ = time_in_process(lambda: decode_capture(data), a.repeats)
    n = int(arr.shape[0])

    chunks = [data[i : i + CHUNK] for i in range(0, len(data), CHUNK)]

    def push() -> tuple[int, Parser]:
        p = Parser()
        k = 0
        for c in chunks:
            k += len(p.feed(c))
        k += len(p.flush())
        return k, p

    push_t, (k, parser) = time_in_process(push, max(1, min(a.repeats, 3)))
    same = k == n and parser.stats == cst
    if same:  # the frames themselves, once (not timed)
        p2 = Parser()
        frames = [f for c in chunks for f in p2.feed(c)]
        same = frames == array_to_frames(arr)
    print(f"push == vectorised (frames and counters): {same}", flush=True)

    rows = [
        ("push parser, 64-byte chunks", push_t, PUSH_TARGET),
        ("vectorised decode_capture", vec, VECTOR_TARGET),
    ]
    lines = _lines(a.repeats, meta, n, rows, first_cpu, cst.bad_frames, same)
    text = "\n".join(lines)
    title = "Decoding: the push parser and the vectorised decoder"
    write_section("speed", title, text, write=not a.no_write)
    print(text)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
