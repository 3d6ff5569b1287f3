"""Fuzz every input surface of hdrd: no traceback, no hang, bounded memory, clear refusals.

    python -m tools.fuzz [--surface all|stream|serial|clock|gpsd|tail|config|bias|capture
                          |drivecsv|driveparquet ...]
                         [--inputs N] [--seconds S] [--seed K] [--hang-s S]
                         [--process | --process-only] [--process-inputs N] [--process-seconds S]
                         [--json FILE] [--show SURFACE:I]

Surfaces (what an attacker, a broken cable or a careless edit can hand hdrd): ``serial``
(the gyro's bytes), ``clock`` (a frame stream whose sequence numbers and device clock break
now and then, each frame with the host time it arrives), ``gpsd`` (lines from whatever answers
on the gpsd address), ``tail``
(UDP datagrams to ``hdrd tail``), ``config`` (the configuration file, at start and on
SIGHUP), ``bias`` (the bias file), ``capture`` (a file for ``hdrd replay``/``convert``),
``drivecsv`` and ``driveparquet`` (drive logs, and the names in them that become paths, for
``hdrd evaluate``/``tune``/``gap``: tools/fuzz/drivelog.py).
``stream`` is the exact-count check of the two frame parsers on a long byte stream
(tools/fuzz/stream.py; ``--bytes``, ``--protocol``).

Each input is a valid one mutated (huge numbers, NaN/inf, deep nesting, wrong types, control
bytes, unicode, giant strings, truncation, YAML anchors and tags, frames whose clock jumps
or whose counts sit at the rails) or random bytes; input *i* of a surface is made from
(seed, surface, i) alone (tools/fuzz/inputs.py), so ``--show SURFACE:I`` writes it to
stdout again. In process, each surface's inputs go through the code the daemon runs
(tools/fuzz/targets.py, tools/fuzz/filetargets.py) in a worker process of its own, which the
parent watches:

- a **traceback** is any exception the code raises, or a broken promise (a non-finite number
  or a heading outside [0, 360) published, a refusal that is not one printable line, tail
  printing a control character, the gpsd client losing step with its peer); each distinct
  one is reported with the first input that gave it;
- a **hang** is an input that takes more than ``--hang-s`` of CPU time, or 15 times that of
  wall-clock time without using CPU (the worker is killed and the run goes on after that
  input); a worker that dies (a crash, the memory limit) is a death;
- **memory**: the worker's peak RSS (``VmHWM``) over all inputs, its RSS before the first
  input and at the end, and the input that raised the peak the most. The worker's address
  space is limited to ``--max-vm-mb`` so that a runaway allocation is a MemoryError (a
  traceback), not the machine's OOM killer.

``--process`` adds the process-level runs (tools/fuzz/process.py): ``hdrd run`` on a pty
written with fuzzed serial bytes, ``hdrd run --gpsd`` against a fuzzing gpsd peer,
``hdrd tail`` receiving fuzzed datagrams, ``hdrd run`` started on fuzzed configuration
and bias files and reloaded (SIGHUP) with fuzzed configurations, ``hdrd replay`` and
``hdrd convert`` on fuzzed captures: exit statuses as documented, one line on stderr for a
refusal, no traceback, a daemon still stepping after every input, its peak RSS.

Exit status 1 if anything failed. Results: bench/RESULTS.md, "Fuzz: every input surface".
"""

from __future__ import annotations

import argparse
import json
import mmap
import multiprocessing as mp
import os
import platform
import resource
import shutil
import struct
import sys
import tempfile
import time
import traceback
from collections import Counter
from dataclasses import asdict
from pathlib import Path
from typing import Any

from . import filetargets, targets
from .drivelog import DriveLogTarget
from .results import SurfaceResult, describe, markdown
from .surfaces import SURFACES, generate
from .targets import Broken

ALL = (*SURFACES, "stream")
"""In the order run: the stream check last, so that the memory it takes (its 10^7-byte
streams) is not in the workers forked for the other surfaces."""


def make_target(surface: str, seed: int, workdir: Path) -> targets.Target:
    """The target of *surface*; hdrd's log is dropped (ConfigTarget reads its events)."""
    targets.quiet_logging()
    if surface == "serial":
        return targets.SerialTarget(seed)
    if surface == "clock":
        return targets.ClockTarget(seed)
    if surface == "gpsd":
        return targets.GpsdTarget(seed)
    if surface == "tail":
        return targets.TailTarget(seed)
    if surface == "config":
        return filetargets.ConfigTarget(seed, workdir)
    if surface == "bias":
        return filetargets.BiasTarget(seed, workdir)
    if surface == "capture":
        return filetargets.CaptureTarget(seed, workdir)
    if surface in ("drivecsv", "driveparquet"):
        return DriveLogTarget(surface, seed, workdir)
    raise ValueError(f"unknown surface {surface!r}")


def _status_kb(field_: str, pid: int | str = "self") -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field_):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


# -- the worker ---------------------------------------------------------------------------------


def _signature(e: BaseException) -> str:
    tb = traceback.extract_tb(e.__traceback__)
    where = next(
        (f"{Path(fr.filename).name}:{fr.lineno}" for fr in reversed(tb) if "/hdrd/" in fr.filename),
        f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else "?",
    )
    if isinstance(e, Broken):
        return f"broken promise at {where}: {str(e)[:120]}"
    return f"{type(e).__name__} at {where}"


def _worker(
    surface: str,
    seed: int,
    start: int,
    stop: int,
    deadline: float,
    progress: Any,
    conn: Any,
    workdir: str,
    max_vm_mb: int,
) -> None:
    if max_vm_mb > 0:
        limit = max_vm_mb << 20
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    res = SurfaceResult(surface, seed)
    outcomes: Counter[str] = Counter()
    target = make_target(surface, seed, Path(workdir))
    hwm = _status_kb("VmHWM")
    res.rss_start_mb = _status_kb("VmRSS") / 1024
    last_send = time.monotonic()
    i = start
    for i in range(start, stop):
        if time.monotonic() > deadline:
            i -= 1
            break
        progress.value = i
        data = generate(surface, seed, i)
        res.largest_input_bytes = max(res.largest_input_bytes, len(data))
        t0 = time.process_time()
        try:
            outcomes[target.run(data)] += 1
        except Exception as e:  # noqa: BLE001 - every exception is what we are looking for
            kind = "broken" if isinstance(e, Broken) else "traceback"
            res.tracebacks += 1
            res.add_defect(kind, _signature(e), i, traceback.format_exc(), len(data))
            outcomes["defect"] += 1
            try:
                target.close()
            except Exception:  # noqa: BLE001, S110 - a broken target is rebuilt either way
                pass
            target = make_target(surface, seed, Path(workdir))
        dt = time.process_time() - t0  # CPU: the machine's load does not move it
        if dt > res.slowest_s:
            res.slowest_s, res.slowest_input = dt, i
        hwm = _note_peak(res, hwm, i, len(data))
        res.inputs += 1
        now = time.monotonic()
        if now - last_send > 2.0:
            _snapshot(res, outcomes, hwm)
            conn.send(("progress", i, res))
            last_send = now
    target.close()
    _snapshot(res, outcomes, hwm)
    conn.send(("done", i, res))


def _note_peak(res: SurfaceResult, hwm: int, i: int, n_bytes: int) -> int:
    """The process's peak RSS (kB) after input ``i``; its largest rise noted in ``res``."""
    h = _status_kb("VmHWM")
    if h > hwm:
        if (h - hwm) / 1024 > res.peak_rise_mb:
            res.peak_rise_mb = (h - hwm) / 1024
            res.peak_rise_input, res.peak_rise_input_bytes = i, n_bytes
        hwm = h
    return hwm


def _snapshot(res: SurfaceResult, outcomes: Counter[str], hwm: int) -> None:
    """The outcomes so far and the memory (MB) into ``res``, to send."""
    res.outcomes, res.peak_rss_mb = dict(outcomes), hwm / 1024
    res.rss_end_mb = _status_kb("VmRSS") / 1024


def _merge(total: SurfaceResult, part: SurfaceResult) -> None:
    total.inputs += part.inputs
    for k, v in part.outcomes.items():
        total.outcomes[k] = total.outcomes.get(k, 0) + v
    for d in part.defects:
        for _ in range(d.count):
            total.add_defect(d.kind, d.signature, d.first_input, d.detail, d.input_bytes)
    total.tracebacks += part.tracebacks
    if part.slowest_s > total.slowest_s:
        total.slowest_s, total.slowest_input = part.slowest_s, part.slowest_input
    total.largest_input_bytes = max(total.largest_input_bytes, part.largest_input_bytes)
    if not total.rss_start_mb:
        total.rss_start_mb = part.rss_start_mb
    total.rss_end_mb = part.rss_end_mb
    total.peak_rss_mb = max(total.peak_rss_mb, part.peak_rss_mb)
    if part.peak_rise_mb > total.peak_rise_mb:
        total.peak_rise_mb = part.peak_rise_mb
        total.peak_rise_input = part.peak_rise_input
        total.peak_rise_input_bytes = part.peak_rise_input_bytes


WALL_FACTOR = 15
"""An input is a hang after ``hang_s`` of the worker's CPU time (a loop), or after this many
times ``hang_s`` of wall-clock time (a wait that uses no CPU: a FIFO, a socket). CPU time,
because on a shared machine a worker at nice 10 beside busy processes can get a few
percent of a core: 20 s of wall clock is no sign of a hang there."""


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process *pid* so far (0 if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class SharedIndex:
    """One int64 shared with forked children through an anonymous ``MAP_SHARED`` mapping."""

    def __init__(self, value: int) -> None:
        self._mm = mmap.mmap(-1, 8)
        self.value = value

    @property
    def value(self) -> int:
        return int(struct.unpack_from("q", self._mm)[0])

    @value.setter
    def value(self, v: int) -> None:
        struct.pack_into("q", self._mm, 0, v)

    def close(self) -> None:
        self._mm.close()


def run_surface(
    surface: str,
    inputs: int,
    seconds: float,
    seed: int,
    hang_s: float = 20.0,
    max_vm_mb: int = 4096,
    quiet: bool = False,
    first: int = 0,
) -> SurfaceResult:
    """Inputs ``first`` .. ``inputs - 1`` of *surface* (or as many as *seconds* allow) through
    its in-process target, in watched worker processes (module doc); ``first`` resumes a
    campaign where an earlier run stopped."""
    ctx = mp.get_context("fork")
    total = SurfaceResult(surface, seed)
    t_start = time.monotonic()
    deadline = t_start + seconds
    start = first
    workdir = tempfile.mkdtemp(prefix=f"hdrd-fuzz-{surface}-")
    try:
        while start < inputs and time.monotonic() < deadline:
            # the input the worker is on: an anonymous shared mapping (no descriptor; the
            # multiprocessing heap behind ctx.Value keeps a /dev/shm file open for good)
            progress = SharedIndex(start - 1)
            recv, send = ctx.Pipe(duplex=False)
            w = ctx.Process(
                target=_worker,
                args=(surface, seed, start, inputs, deadline, progress, send, workdir, max_vm_mb),
                daemon=True,
            )
            w.start()
            send.close()
            pid = w.pid
            assert pid is not None
            last, done_at, hung = _watch(w, pid, recv, progress, surface, hang_s, quiet)
            w.join()
            recv.close()
            cur = progress.value
            progress.close()
            if last is not None:
                _merge(total, last)
            if done_at is not None:
                start = inputs
                break
            # killed (a hang) or died: the input it was on is the culprit; go on after it
            _count_lost(total, surface, seed, cur, hung, w.exitcode, last, start)
            start = cur + 1
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    total.seconds = time.monotonic() - t_start
    return total


def _watch(
    w: Any, pid: int, recv: Any, progress: SharedIndex, surface: str, hang_s: float, quiet: bool
) -> tuple[SurfaceResult | None, int | None, str]:
    """A worker watched until it is done, dies or hangs (then killed): its last report, the
    input it finished at (None unless done), why it was killed ("" unless it hung)."""
    last: SurfaceResult | None = None
    seen, seen_at, seen_cpu = progress.value, time.monotonic(), 0.0
    while True:
        if recv.poll(0.25):
            try:
                kind, at, res = recv.recv()
            except EOFError:
                kind = ""
            else:
                last = res
                if kind == "done":
                    return last, at, ""
                if not quiet:
                    print(f"  {surface}: {at + 1:,} inputs", end="\r", file=sys.stderr, flush=True)
                continue
        if not w.is_alive():
            return last, None, ""
        cur = progress.value
        hung = ""
        if cur != seen:
            seen, seen_at, seen_cpu = cur, time.monotonic(), _cpu_s(pid)
        elif _cpu_s(pid) - seen_cpu > hang_s:
            hung = f"{hang_s:g} s of CPU on one input"
        elif time.monotonic() - seen_at > WALL_FACTOR * hang_s:
            hung = f"no progress for {WALL_FACTOR * hang_s:g} s (waiting)"
        if hung:
            w.kill()
            return last, None, hung


def _count_lost(
    total: SurfaceResult,
    surface: str,
    seed: int,
    cur: int,
    hung: str,
    exitcode: int | None,
    last: SurfaceResult | None,
    start: int,
) -> None:
    """A worker killed (a hang) or dead on input ``cur``: the defect, and the inputs after
    its last report counted."""
    data = generate(surface, seed, cur)
    if hung:
        total.hangs += 1
        total.add_defect("hang", hung, cur, "", len(data))
    else:
        total.deaths += 1
        total.add_defect("death", f"worker exit {exitcode}", cur, "", len(data))
    counted = (last.inputs if last is not None else 0) + start
    total.inputs += max(0, cur - counted) + 1  # the inputs after the last report


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument(
        "--surface",
        nargs="+",
        choices=("all", *ALL),
        default=["all"],
        help="surfaces to fuzz (default all)",
    )
    ap.add_argument("--inputs", type=int, default=2000, help="inputs per surface (default 2000)")
    ap.add_argument(
        "--first",
        type=int,
        default=0,
        help="start at this input (default 0): resumes a campaign, up to --inputs",
    )
    ap.add_argument(
        "--seconds",
        type=float,
        default=600.0,
        help="at most this long per surface, s (default 600); whichever ends first",
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of every input (default 0)")
    ap.add_argument(
        "--hang-s",
        type=float,
        default=20.0,
        help="an input taking more CPU seconds hangs (default 20; 15x as many wall seconds)",
    )
    ap.add_argument(
        "--max-vm-mb",
        type=int,
        default=4096,
        help="address-space limit of a worker, MiB (default 4096; 0: none)",
    )
    _process_options(ap)
    ap.add_argument("--bytes", type=int, default=10_000_000, help="stream: length per protocol")
    ap.add_argument(
        "--protocol",
        choices=("hdr-bin", "hdr-text", "both"),
        default="both",
        help="stream: which protocol (default both)",
    )
    ap.add_argument("--json", metavar="FILE", help="write the results as JSON")
    ap.add_argument(
        "--show", metavar="SURFACE:I", help="write input I of SURFACE to stdout, and exit"
    )
    return ap


def _process_options(ap: argparse.ArgumentParser) -> None:
    """The options of the process-level runs."""
    ap.add_argument("--process", action="store_true", help="also the process-level runs")
    ap.add_argument("--process-only", action="store_true", help="only the process-level runs")
    ap.add_argument(
        "--process-inputs",
        type=int,
        default=200,
        help="inputs per process-level run that starts a process per input (default 200)",
    )
    ap.add_argument(
        "--process-seconds",
        type=float,
        default=60.0,
        help="seconds per process-level run against one long-running process (default 60)",
    )
    ap.add_argument(
        "--process-stream-inputs",
        type=int,
        default=100_000,
        help="at most this many inputs per long-running process (default 100000)",
    )


def _in_process(args: argparse.Namespace, surfaces: tuple[str, ...], doc: dict[str, Any]) -> bool:
    """Every surface's inputs in process (the stream surface by tools/fuzz/stream.py), each
    described; the results into ``doc``; whether all were OK."""
    ok = True
    results: list[SurfaceResult] = []
    for s in surfaces:
        if s == "stream":
            from . import stream as fuzz_stream

            argv_s = ["--bytes", str(args.bytes), "--seed", str(args.seed), "--protocol",
                      args.protocol]  # fmt: skip
            ok &= fuzz_stream.main(argv_s) == 0
            continue
        r = run_surface(
            s, args.inputs, args.seconds, args.seed, args.hang_s, args.max_vm_mb, first=args.first
        )
        results.append(r)
        ok &= r.ok
        print(describe(r), flush=True)
        doc["in_process"].append(asdict(r))
    if results:
        print("\n" + markdown(results))
    return ok


def _as_processes(args: argparse.Namespace, surfaces: tuple[str, ...], doc: dict[str, Any]) -> bool:
    """The process-level runs of every surface but the stream, each described; the results
    into ``doc``; whether all were OK."""
    from . import process as fuzz_process

    ok = True
    for s in surfaces:
        if s not in fuzz_process.PROCESS_SURFACES:  # the stream's run is apart; the rest in process
            continue
        for pr in fuzz_process.run(
            s, args.seed, args.process_inputs, args.process_seconds, args.process_stream_inputs
        ):
            ok &= pr.ok
            print(pr.describe(), flush=True)
            doc["process"].append(asdict(pr))
    return ok


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.show:
        surface, _, i = args.show.partition(":")
        if surface not in SURFACES or not i.isdigit():
            ap.error(f"--show wants SURFACE:I with SURFACE one of {', '.join(SURFACES)}")
        sys.stdout.buffer.write(generate(surface, args.seed, int(i)))
        return 0
    surfaces = ALL if "all" in args.surface else tuple(s for s in ALL if s in args.surface)
    import numpy as np

    print(
        f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}, "
        f"load average {os.getloadavg()[0]:.2f}",
        flush=True,
    )
    ok = True
    doc: dict[str, Any] = {"seed": args.seed, "in_process": [], "process": []}
    if not args.process_only:
        ok &= _in_process(args, surfaces, doc)
    if args.process or args.process_only:
        ok &= _as_processes(args, surfaces, doc)
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n")
    print("OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
