#!/usr/bin/env python3
"""Replay: wall time of ``hdrd replay`` on a 1-hour 100 Hz capture, end to end as a process.

    python bench/replay.py [--repeats 5] [--workdir /tmp/hdrd-bench] [--no-write]

Takes about 15 s (the first run also writes the capture, ~3 s). ``hdrd replay CAPTURE --bias
0.1`` runs as a process (the console script beside this Python): interpreter start-up, imports,
reading and decoding the capture, the pipeline and one JSON line per step, written to a file
(and, apart, to /dev/null). The figure is the wall time from spawn to exit; also the child's CPU
time (user + system) and the multiple of real time (device time / wall time). A breakdown by
phase comes from one more run in a fresh interpreter that times each phase itself.

Target: <= 0.5 s, i.e. >= 7,200x real time. Prints the figures and
writes its section of bench/RESULTS.md (Speed).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import (
    REPO,
    Timing,
    capture_bench_setup,
    capture_line,
    hdrd_command,
    machine_line,
    ratio,
    time_process,
    write_section,
)

TARGET_S = 0.5
BIAS = "0.1"

# One replay in a fresh interpreter, timing its own phases (what `hdrd replay` does, in order).
PHASES = r"""
import json, sys, time
t = [time.perf_counter()]
import numpy
t.append(time.perf_counter())
from hdrd.cli import build_parser
from hdrd.core.calibrate import given_bias
from hdrd.io.wire.capture import decode_capture
from hdrd.configload import load_config
from hdrd.daemon.pipeline import Pipeline, pipeline_config
from hdrd.io.net.formats import format_json
t.append(time.perf_counter())
args = build_parser().parse_args(["replay", sys.argv[1], "--bias", sys.argv[2]])
cfg, _ = load_config(args.config)  # replay's flags here override no key
data = open(sys.argv[1], "rb").read()
t.append(time.perf_counter())
frames, stats = decode_capture(data)
t.append(time.perf_counter())
p = Pipeline(pipeline_config(cfg, given_bias(float(sys.argv[2]))))
msgs = p.feed_array(frames, stats.bad_before)
msgs.extend(p.finish(int(stats.bad_frames)))
t.append(time.perf_counter())
out = b"".join(format_json(m) for m in msgs)
t.append(time.perf_counter())
with open("/dev/null", "wb") as f:
    f.write(out)
t.append(time.perf_counter())
names = ["import numpy", "import hdrd's modules", "arguments, configuration, read the file",
         "decode (decode_capture)", "pipeline (feed_array)", "JSON (format_json)", "write"]
print(json.dumps({n: b - a for n, a, b in zip(names, t, t[1:])}))
"""


def _measure(
    cmd: list[str], cap: Path, work: Path, repeats: int
) -> tuple[int, Timing, Timing, Timing, dict[str, float]]:
    """``cmd`` (the replay) timed to a file and to /dev/null, the interpreter's start alone,
    and the phases of one more run (s): with the JSON lines it writes."""
    out_file = work / "replay.jsonl"
    with open(out_file, "wb") as f:
        subprocess.run(
            cmd, stdout=f, check=True
        )  # warm the page cache; also the output checked below
    lines = out_file.read_bytes().count(b"\n")
    with open(out_file, "wb") as f:
        to_file = time_process(cmd, repeats, stdout=f)
    to_null = time_process(cmd, repeats)
    python_alone = time_process([sys.executable, "-c", "pass"], repeats)
    phases = json.loads(
        subprocess.run(
            [sys.executable, "-c", PHASES, str(cap), BIAS],
            capture_output=True,
            text=True,
            check=True,
            cwd=REPO,
        ).stdout
    )
    return lines, to_file, to_null, python_alone, phases


def main(argv: list[str] | None = None) -> int:
    a, cap, meta = capture_bench_setup(__doc__, argv)
    work = cap.parent
    hdrd = hdrd_command()
    cmd = [*hdrd, "replay", str(cap), "--bias", BIAS]
    lines, to_file, to_null, python_alone, phases = _measure(cmd, cap, work, a.repeats)
    dev_s = meta["device_s"]
    how = "the console script" if len(hdrd) == 1 else "python -m hdrd"
    rows = [("> a file", to_file), ("> /dev/null", to_null)]
    md = [
        f"`python bench/replay.py --repeats {a.repeats}` on {machine_line()}.",
        "",
        (
            f"Capture: {capture_line(meta)}. `hdrd replay CAPTURE --bias {BIAS}` as a process ({how}), "
            f"{lines:,} JSON lines; wall time from spawn to exit (best and median of {a.repeats}), the "
            "child's CPU time (user + system), and device time / wall time."
        ),
        "",
        "| output | best wall | median wall | CPU | x real time | target <= 0.5 s | vs target |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, t in rows:
        md.append(
            f"| {name} | {t.best_wall:.3f} s | {t.median_wall:.3f} s | {t.best_cpu:.3f} s | "
            f"{dev_s / t.best_wall:,.0f}x | {'met' if t.best_wall <= TARGET_S else 'missed'} | "
            f"{ratio(t.best_wall, TARGET_S, False)} |"
        )
        print(
            f"replay {name}: best {t.best_wall:.3f} s, median {t.median_wall:.3f} s, CPU {t.best_cpu:.3f} s, {dev_s / t.best_wall:,.0f}x real time",
            flush=True,
        )
    md += [
        "",
        (
            f"Where the time goes (one more run, in a fresh interpreter, timing itself; the interpreter's "
            f"own start-up, `python -c pass`, is {python_alone.best_wall * 1e3:.0f} ms on its own):"
        ),
        "",
        "| phase | ms |",
        "|---|---|",
    ]
    md += [f"| {k} | {v * 1e3:.0f} |" for k, v in phases.items()]
    text = "\n".join(md)
    title = "Replay of a 1-hour capture, as a process"
    write_section("speed", title, text, write=not a.no_write)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
