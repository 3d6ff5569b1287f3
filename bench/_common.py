"""Shared helpers of the benchmarks: the machine's description, timing helpers, the 1-hour
test capture, the scoring that more than one script needs (NEψ of a yaw, means per drive type
and the share of drives worse than a reference over a set, the bias oracle of a simulated
drive), and report writing (a command run and recorded, a figure formatted, a script's own
section of bench/RESULTS.md replaced in place or added at the end of its part).

Benchmarks measure; tests never assert timings. Every figure is reported with the machine it
was taken on, including the load average at the time: this 2-core machine is shared with other
jobs, so wall-clock figures vary from run to run; CPU-time figures (what the process itself
spent) vary much less, and each script prints both.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    import numpy as np

    from hdrd.analysis.evaluate import PreparedDrive
    from hdrd.core.plusparams import PlusParams
    from hdrd.io.files.drivelog import DriveLog

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "RESULTS.md"
sys.path.insert(0, str(REPO))

WIRE_BAUD = 3_000_000
"""The fastest serial link the ADC would use, baud (8N1: 10 bits on the wire per byte)."""
WIRE_FRAMES_PER_S = WIRE_BAUD / 10 / 16
"""The most hdr-bin frames (16 bytes) a 3 Mbaud link can carry per second: 18,750."""


# --------------------------------------------------------------------------- the machine


def _read(path: str) -> str:
    try:
        return Path(path).read_text()
    except OSError:
        return ""


def cpu_model() -> str:
    for line in _read("/proc/cpuinfo").splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def ram_gb() -> float:
    for line in _read("/proc/meminfo").splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) / 1024 / 1024
    return float("nan")


def git_commit() -> str:
    """Short commit of the working tree, "+dirty" when hdrd/ or bench/ (results aside) has
    uncommitted changes."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "hdrd", "bench", ":!bench/RESULTS.md"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+dirty" if dirty else "")


def loadavg() -> str:
    parts = _read("/proc/loadavg").split()
    return " ".join(parts[:3]) if parts else "?"


def machine() -> dict[str, str]:
    """What the figures were measured on."""
    import numpy as np

    return {
        "cpu": cpu_model(),
        "cores": str(os.cpu_count()),
        "ram": f"{ram_gb():.1f} GB",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "kernel": f"{platform.system()} {platform.release()}",
        "commit": git_commit(),
        "load": loadavg(),
    }


def machine_line(m: dict[str, str] | None = None) -> str:
    m = m or machine()
    return (
        f"{m['cpu']}, {m['cores']} cores, {m['ram']} RAM, Python {m['python']}, numpy {m['numpy']}, "
        f"{m['kernel']}, commit {m['commit']}; load average (1/5/15 min) at start {m['load']}"
    )


# --------------------------------------------------------------------------- timing


@dataclass(frozen=True)
class Timing:
    """Repeated measurements of one thing: wall and CPU seconds of each run."""

    wall: list[float]
    cpu: list[float]

    @property
    def best_wall(self) -> float:
        return min(self.wall)

    @property
    def median_wall(self) -> float:
        return statistics.median(self.wall)

    @property
    def best_cpu(self) -> float:
        return min(self.cpu)


def time_in_process(fn: Callable[[], Any], repeats: int) -> tuple[Timing, Any]:
    """Run ``fn`` ``repeats`` times; wall (perf_counter) and CPU (process_time) of each."""
    wall: list[float] = []
    cpu: list[float] = []
    result: Any = None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        result = fn()
        w1, c1 = time.perf_counter(), time.process_time()
        wall.append(w1 - w0)
        cpu.append(c1 - c0)
    return Timing(wall, cpu), result


def time_process(
    cmd: Sequence[str],
    repeats: int,
    stdout: Any = subprocess.DEVNULL,
    env: dict[str, str] | None = None,
) -> Timing:
    """Run a command ``repeats`` times: wall seconds from spawn to exit, and the child's CPU
    seconds (user + system, from its rusage). Fails loudly if the command fails."""
    wall: list[float] = []
    cpu: list[float] = []
    for _ in range(repeats):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        p = subprocess.run(list(cmd), stdout=stdout, stderr=subprocess.PIPE, env=env, check=False)
        w1 = time.perf_counter()
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode != 0:
            raise SystemExit(
                f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr.decode(errors='replace')}"
            )
        wall.append(w1 - w0)
        cpu.append((r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return Timing(wall, cpu)


def hdrd_command() -> list[str]:
    """How a user runs hdrd: the console script installed beside this Python (not a pyenv
    shim, which adds its own start-up), else ``python -m hdrd``."""
    script = Path(sys.executable).with_name("hdrd")
    if script.is_file() and os.access(script, os.X_OK) and script.read_bytes()[:2] == b"#!":
        return [str(script)]
    found = shutil.which("hdrd")
    if found and "shims" not in found:
        return [found]
    return [sys.executable, "-m", "hdrd"]


# --------------------------------------------------------------------------- the capture

CAPTURE_MINUTES = 60.0
CAPTURE_HZ = 100.0
CAPTURE_GARBAGE = 0.01
"""Probability of a run of 1..32 garbage bytes before a frame: ~1 % of the bytes."""
CAPTURE_CRC_ERRORS = 0.001
"""Probability of a frame with a flipped bit (a CRC error)."""
CAPTURE_SEED = 1


def make_capture(
    path: Path, minutes: float = CAPTURE_MINUTES, hz: float = CAPTURE_HZ, seed: int = CAPTURE_SEED
) -> dict[str, Any]:
    """Write the benchmark capture: the simulated "mixed" drive (``hdrd.sim``) at ``hz`` through
    the fake gyro's encoder with 1 % garbage and 0.1 % CRC errors. Returns what went in.
    Cached: an existing file with a matching ``.meta`` is reused."""
    import json

    meta = path.with_suffix(path.suffix + ".meta")
    key = {
        "minutes": minutes,
        "hz": hz,
        "seed": seed,
        "garbage": CAPTURE_GARBAGE,
        "crc_errors": CAPTURE_CRC_ERRORS,
    }
    if path.exists() and meta.exists():
        m = json.loads(meta.read_text())
        if m.get("key") == key:
            return m
    from hdrd.sim import simulate_drive
    from hdrd.sim.fakegyro import FakeGyro

    profile = simulate_drive("mixed", minutes, seed, hz=hz)
    g = FakeGyro(profile, garbage=CAPTURE_GARBAGE, crc_errors=CAPTURE_CRC_ERRORS, seed=seed)
    g.write_capture(path)
    size = path.stat().st_size
    m = {
        "key": key,
        "frames_total": int(g.frames.shape[0]),
        "frames": g.injected.frames,
        "crc_errors": g.injected.crc_errors,
        "garbage_bytes": g.injected.garbage_bytes,
        "bytes": size,
        "device_s": float(g.t_s[-1]),
    }
    meta.write_text(json.dumps(m))
    return m


def capture_bench_setup(doc: str, argv: list[str] | None) -> tuple[Any, Path, dict[str, Any]]:
    """The start of a benchmark on the 1-hour capture (bench/decode.py, bench/replay.py):
    parse ``--repeats``, ``--workdir`` and ``--no-write``, print the machine, make (or reuse)
    the capture in the work directory and describe it. Returns (args, capture path, meta)."""
    import argparse

    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--workdir", default="/tmp/hdrd-bench", help="where the capture is kept")
    ap.add_argument("--no-write", action="store_true", help="print only; do not write RESULTS.md")
    a = ap.parse_args(argv)
    work = Path(a.workdir)
    work.mkdir(parents=True, exist_ok=True)
    print(machine_line(), flush=True)
    cap = work / "capture-1h-100hz.bin"
    meta = make_capture(cap)
    print(capture_line(meta), flush=True)
    return a, cap, meta


def capture_line(m: dict[str, Any]) -> str:
    return (
        f'{m["device_s"] / 3600:.2f} h of the simulated "mixed" drive at {m["key"]["hz"]:g} Hz, '
        f"{m['bytes']:,} bytes: {m['frames']:,} good frames, {m['crc_errors']:,} with a CRC error, "
        f"{m['garbage_bytes']:,} garbage bytes ({m['garbage_bytes'] / m['bytes']:.1%})"
    )


# --------------------------------------------------------------------------- results


def ratio(value: float, target: float, higher_is_better: bool) -> str:
    """ "2.3x the target" (better) or "0.6x the target" (worse), as a margin: > 1 means met."""
    r = value / target if higher_is_better else target / value
    return f"{r:.2f}x"


Topic = Literal["speed", "real", "sim", "gap", "reliability"]
TOPICS: dict[str, str] = {
    "speed": "# Speed",
    "real": "# Accuracy: real drives",
    "sim": "# Accuracy: simulated drives",
    "gap": "# Model gap",
    "reliability": "# Reliability",
}
"""The parts of bench/RESULTS.md, in order; each script names the part its sections live in."""


def _headings(lines: list[str]) -> list[tuple[int, int]]:
    """(line index, level) of each ``# `` and ``## `` heading outside fenced code."""
    found, fenced = [], False
    for i, line in enumerate(lines):
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith(("# ", "## ")):
            found.append((i, 1 if line.startswith("# ") else 2))
    return found


def placed(text: str, topic: Topic, section: str) -> str:
    """``text`` (RESULTS.md's) with ``section``, whose first line is its ``## `` heading, in place
    of the section with that heading wherever it is, else at the end of the part ``topic``
    (the part added at the end if missing). A section runs to the next ``#`` or ``##`` heading."""
    lines = text.splitlines(keepends=True)
    marks = _headings(lines)
    heading = section.splitlines()[0].rstrip()
    start = next((i for i, lvl in marks if lvl == 2 and lines[i].rstrip() == heading), None)
    if start is not None:
        end = next((i for i, _ in marks if i > start), len(lines))
    else:
        part = next(
            (i for i, lvl in marks if lvl == 1 and lines[i].rstrip() == TOPICS[topic]), None
        )
        if part is None:
            return f"{text.rstrip()}\n\n{TOPICS[topic]}\n\n{section.rstrip()}\n"
        start = end = next((i for i, lvl in marks if lvl == 1 and i > part), len(lines))
    before = "".join(lines[:start]).rstrip()
    after = "".join(lines[end:]).lstrip("\n")
    return f"{before}\n\n{section.rstrip()}\n" + (f"\n{after}" if after else "")


def put_section(topic: Topic, section: str, write: bool = True) -> str:
    """Write ``section`` (``## heading`` first) into bench/RESULTS.md where :func:`placed` puts
    it, leaving every other section as it is; returns the section. ``write=False`` only returns
    it."""
    if write:
        text = RESULTS.read_text(encoding="utf-8") if RESULTS.exists() else ""
        RESULTS.write_text(placed(text or "# hdrd benchmark results\n", topic, section), "utf-8")
    return section


def write_section(topic: Topic, title: str, body: str, write: bool = True) -> str:
    """:func:`put_section` of ``## <title>`` (a heading that stays the same from run to run, so
    that a run replaces the last one) with ``body`` headed by the date; the body gives the
    command and :func:`machine_line` (with the commit)."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return put_section(topic, f"## {title}\n\n({stamp}) {body.strip()}\n", write)


# --------------------------------------------------------------------------- report writing


def run_recorded(cmd: list[str], shown: list[str]) -> subprocess.CompletedProcess[str]:
    """Run a command from the repository root as a user would, append it to ``shown`` (as
    the report lists it: ``python`` for this interpreter), print its time; stop the benchmark
    with the command's output if it fails."""
    text = " ".join(shlex.quote(c) for c in cmd).replace(sys.executable, "python")
    print(f"$ {text}", flush=True)
    shown.append(text)
    t0 = time.monotonic()
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, check=False)
    if p.returncode != 0:
        sys.stderr.write(p.stdout + p.stderr)
        raise SystemExit(f"command failed ({p.returncode}): {text}")
    print(f"  ({time.monotonic() - t0:.1f} s)", flush=True)
    return p


def fmt(v: float | None, d: int = 3) -> str:
    """A figure with ``d`` decimals; a dash for a missing or non-finite one."""
    return "–" if v is None or not math.isfinite(v) else f"{v:.{d}f}"


# --------------------------------------------------------------------------- scoring


def ne_psi(prep: PreparedDrive, yaw: np.ndarray, drop: int = 0) -> float:
    """NEψ (deg/min, paper Eq. 13) of ``yaw`` (deg, one per step of ``prep``) over the steps
    from ``drop`` on, aligned at the first step with truth there."""
    from hdrd.analysis.metrics import align_index, e_psi

    truth = prep.truth[drop:]
    y = yaw[drop:]
    k = align_index(y, truth)
    return float(e_psi(y, truth, k)) / (y.shape[0] * prep.steps.T / 60.0)


def type_means(values: Sequence[float] | np.ndarray, kinds: Sequence[str]) -> dict[str, float]:
    """Mean of ``values`` per drive type (``kinds[i]`` is drive i's type), in order of first
    appearance."""
    import numpy as np

    v = np.asarray(values, dtype=np.float64)
    k = np.asarray(kinds, dtype=object)
    return {t: float(np.mean(v[k == t])) for t in dict.fromkeys(kinds)}


def share_worse(
    values: Sequence[float] | np.ndarray, ref: Sequence[float] | np.ndarray, factor: float = 1.1
) -> float:
    """Share of drives whose figure exceeds ``factor`` x the reference's on the same drive
    (the single-drive criterion: NEψ above 1.1 x paper HDR's)."""
    import numpy as np

    return float(np.mean(np.asarray(values) > factor * np.asarray(ref)))


def true_gyro_error(log: DriveLog) -> np.ndarray:
    """Per sample, the simulated gyro's output minus its true rate times the gyro's scale
    factor (from the log's ``gyro_model`` metadata, 1 if none), deg/s: its bias and noise,
    known in simulation only."""
    gain = 1.0
    for e in json.loads(log.meta.get("gyro_model", "[]")):
        if e.get("name") == "scale_factor":
            gain = 1.0 + float(e["error"])
    assert log.omega_truth is not None
    return log.omega - gain * log.omega_truth


def oracle_yaw(
    log: DriveLog, prep: PreparedDrive, extra: np.ndarray | None = None, window_s: float = 121.0
) -> np.ndarray:
    """Yaw (deg, one per step of ``prep``) with the gyro's true error (:func:`true_gyro_error`
    per step, averaged over ``window_s`` centred, a window cut to the log at its ends, plus
    ``extra``, an error added per step,
    deg/s) removed from every step, white noise left in: a smoother's bias, known in
    simulation only; not causal, a bound no real-time method reaches."""
    import numpy as np

    err = true_gyro_error(log)
    t = log.t - log.t[0]
    T = prep.steps.T
    idx = np.floor(t / T + 1e-9).astype(np.int64)
    n_all = int(idx[-1]) + 1
    sums = np.bincount(idx, weights=err, minlength=n_all)
    counts = np.bincount(idx, minlength=n_all)
    step_err = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)
    k = max(1, int(round(window_s / T)))
    # the window shrinks at the ends to the steps there are: zeros beyond the ends would take
    # a bias B for B/2 there, and repeating the end step would weigh its noise 60 times
    ones = np.ones(k)
    smooth = np.convolve(step_err, ones, mode="same") / np.convolve(
        np.ones(n_all), ones, mode="same"
    )
    first = int(round(prep.start_s / T))
    corr = smooth[first : first + prep.steps.u.shape[0]] - prep.steps.bias_dps
    if extra is not None:
        corr = corr + extra
    # u = raw - eps0 = true + err - eps0: removing (err - eps0) leaves the true rate.
    return np.cumsum((prep.steps.u - corr) * T)


# --------------------------------------------------------------------------- HDR+ experiments


def plus_with(base: PlusParams | None = None, **kw: Any) -> PlusParams:
    """HDR+'s settings with some values overridden by flat name, for experiments on tuning
    data: a field of :class:`hdrd.core.plusparams.PlusParams` by its name; ``bank`` as a list
    of mappings of :class:`~hdrd.core.plusparams.Hypothesis`'s fields. (The road model and the
    other constants of :mod:`hdrd.core.plusparams` are edited there.)"""
    from dataclasses import replace

    from hdrd.core.plusparams import DEFAULTS, Hypothesis

    p = DEFAULTS if base is None else base
    if "bank" in kw:
        kw["bank"] = tuple(Hypothesis(**h) for h in kw["bank"])
    return replace(p, **kw)
