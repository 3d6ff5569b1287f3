"""GNSS outages, offline: a drive through the daemon's own GPS-aiding path with the fixes cut
out every so often, and the heading error at the end of each cut. Pure.

The daemon with gpsd (docs/gps-aiding.md) aligns its heading to the GPS course and learns the
static bias from it (:class:`hdrd.daemon.aiding.GpsAiding`); in a tunnel, a garage or a city
canyon it dead-reckons on the gyro, and the drift reducer's work is what is left of the
heading when the fix comes back. :func:`run_outages` replays a prepared drive
(:func:`hdrd.analysis.prepare.prepare_drive`) step by step as the daemon would have run it:

1. the fixes: the log's ``gps_course``/``gps_speed`` at their rows, or, where it has no
   separate GPS, its ``heading_truth`` and ``speed`` (one fix per truth sample), each handed
   to :meth:`~hdrd.daemon.aiding.GpsAiding.on_fix` at its time, except inside an outage;
2. each step: the speed the pipeline would have from gpsd (:meth:`~hdrd.daemon.aiding.
   GpsAiding.speed`: none in an outage), then the daemon's own stepper
   (:class:`hdrd.daemon.pipeline.Stepper`) with its GPS aiding stage: the method's step on u =
   block mean - the static bias in force, the aiding's view of it (a course for a method that
   estimates the bias itself, HDR+, as its next step's measurement; a learned correction of
   the static bias for the others), the message the daemon publishes;
3. at the end of each outage, the published (aligned) heading against the truth.

``none`` through this path is *aiding with the bias frozen at the outage's start*: the static
bias the aiding learned before it, no drift reduction inside it. Outages follow
:class:`OutageSpec`: one of D seconds at the end of every period of P seconds of the drive
(from the end of its calibration), e.g. ``120s/10min``; only outages wholly inside the drive
count, and one whose end has no truth is not scored. Units: heading compass deg (clockwise),
rates deg/s CCW, time s since the log's first sample.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from hdrd.analysis.prepare import DEFAULTS, PAPER_PARAMS, EvaluationError, PreparedDrive
from hdrd.core.angles import wrap180
from hdrd.core.calibrate import BiasRecord
from hdrd.core.methods import MethodSetup
from hdrd.core.resample import Block
from hdrd.daemon.aiding import AidingConfig, GpsAiding
from hdrd.daemon.stepper import PipelineConfig, Stepper
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "FROZEN",
    "LogFix",
    "OutageResult",
    "OutageSpec",
    "drive_fixes",
    "format_outages",
    "outage_windows",
    "outages_json",
    "pooled",
    "run_outages",
]

FloatArray = npt.NDArray[np.float64]

FROZEN = "none"
"""The method that is "aiding, bias frozen at the outage start": static bias removal, the bias
the aiding learned before the outage."""

_UNITS = {"": 1.0, "s": 1.0, "min": 60.0, "h": 3600.0}
_SPEC_RE = re.compile(
    r"^\s*([0-9]+(?:\.[0-9]+)?)\s*(s|min|h)?\s*/\s*([0-9]+(?:\.[0-9]+)?)\s*(s|min|h)?\s*$"
)


@dataclass(frozen=True)
class OutageSpec:
    """One outage of ``duration_s`` at the end of every ``period_s`` of the drive, s."""

    duration_s: float
    period_s: float

    @classmethod
    def parse(cls, text: str, step_s: float = PAPER_PARAMS.T) -> OutageSpec:
        """``D/P`` with units s (the default), min or h: ``120s/10min``, ``90/600``; the
        duration at least one step of ``step_s`` (the drift reducer's T, s: a shorter outage
        cuts no fix, and a period as short makes millions of outages). ValueError saying what
        is allowed."""
        m = _SPEC_RE.match(text)
        if m is None:
            raise ValueError(
                f"outages {text!r}: expected DURATION/PERIOD with units s, min or h, e.g. "
                "120s/10min (an outage of 120 s every 10 minutes of driving)"
            )
        d = float(m.group(1)) * _UNITS[m.group(2) or ""]
        p = float(m.group(3)) * _UNITS[m.group(4) or ""]
        if not (0.0 < d < p):
            raise ValueError(
                f"outages {text!r}: the duration must be > 0 and shorter than the period "
                f"({d:g} s every {p:g} s)"
            )
        if d < step_s:
            raise ValueError(
                f"outages {text!r}: an outage of {d:g} s is shorter than a step ({step_s:g} s, "
                "hdr.T); give at least one step"
            )
        return cls(d, p)

    def __str__(self) -> str:
        return f"{self.duration_s:g}s/{self.period_s:g}s"


def outage_windows(
    spec: OutageSpec, start_s: float, end_s: float, phase_s: float = 0.0
) -> list[tuple[float, float]]:
    """The outages of a drive from ``start_s`` to ``end_s`` (s): [start + phase + k P - D,
    start + phase + k P) for k = 1, 2, ... while wholly inside it; ``phase_s`` (s) starts the
    grid that much later (other instants of the same drive)."""
    out = []
    k = 1
    while start_s + phase_s + k * spec.period_s <= end_s + 1e-9:
        stop = start_s + phase_s + k * spec.period_s
        out.append((stop - spec.duration_s, stop))
        k += 1
    return out


class LogFix(NamedTuple):
    """A GPS fix made from a drive log's row (:class:`hdrd.daemon.aiding.FixLike`): a 3D fix
    with a course (compass deg) and a ground speed (m/s); no error estimates."""

    mode: int
    track_deg: float | None
    speed_mps: float | None
    epd: float | None = None
    eps: float | None = None
    device: str | None = "log"


def drive_fixes(log: DriveLog) -> tuple[FloatArray, list[LogFix]]:
    """(times s, fixes) of a drive log: its ``gps_course``/``gps_speed`` rows, else its
    ``heading_truth``/``speed`` rows (a fix per truth sample); and, once a second where it
    has no course, a fix with the log's ``speed`` alone (a receiver reports its speed at a
    stop, where its course means nothing). EvaluationError without a course column."""
    course, speed = log.gps_course, log.gps_speed
    if course is None:
        course, speed = log.heading_truth, log.speed
    if course is None:
        raise EvaluationError(
            f"{log.name}: no gps_course or heading_truth column to aid the heading from"
        )
    t0 = float(log.t[0])
    out: list[tuple[float, LogFix]] = []
    for i in np.flatnonzero(np.isfinite(course)).tolist():
        v = float(speed[i]) if speed is not None and math.isfinite(speed[i]) else None
        out.append((float(log.t[i]) - t0, LogFix(3, float(course[i]) % 360.0, v)))
    if log.speed is not None:
        bare = ~np.isfinite(course) & np.isfinite(log.speed)
        second = np.floor(np.asarray(log.t, dtype=np.float64) - t0)
        first = np.concatenate(([True], np.diff(second) > 0))  # a row a second
        for i in np.flatnonzero(bare & first).tolist():
            out.append((float(log.t[i]) - t0, LogFix(3, None, float(log.speed[i]))))
    out.sort(key=lambda tf: tf[0])
    t = np.array([tf[0] for tf in out], dtype=np.float64)
    return t, [tf[1] for tf in out]


@dataclass(frozen=True)
class OutageResult:
    """One drive's outages and each method's heading error at their ends.

    windows: (start, end) of each outage, s since the log's first sample. errors: per method,
    the published heading minus the truth at each outage's last step, deg, wrapped to
    [-180, 180) (NaN where the truth is unknown there). aided_steps: steps with the heading
    aligned to a fix (per method: the gate may reject a course for one and not another).
    trace: one value per step (:data:`TRACE_COLUMNS`): ``t`` (s, the step's end),
    ``in_outage`` (1 inside an outage, else 0), ``heading_truth`` (compass deg, as the
    gyro-only trace has it), ``heading_frozen``, ``heading_hdr``, ``heading_hdr+`` (each
    method's published heading, compass deg, NaN before its first alignment; ``frozen`` is
    ``none``) and ``heading_sd_hdr+`` (deg, 1 sigma) -- the columns of ``hdrd evaluate
    --outages --trace DIR``'s DIR/<drive>.outages.csv, for the methods run.
    """

    name: str
    spec: OutageSpec
    windows: tuple[tuple[float, float], ...]
    methods: tuple[str, ...]
    errors: dict[str, FloatArray]
    aided_steps: dict[str, int]
    trace: dict[str, FloatArray] | None = None

    def mean_abs(self, method: str) -> float:
        """Mean |error| at the end of the scored outages, deg (NaN with none)."""
        e = np.abs(self.errors[method])
        e = e[np.isfinite(e)]
        return float(np.mean(e)) if e.shape[0] else math.nan

    @property
    def scored(self) -> int:
        """Outages whose end has a truth heading."""
        first = self.errors[self.methods[0]] if self.methods else np.empty(0)
        return int(np.count_nonzero(np.isfinite(first)))


def _in_outage(t: float, windows: Sequence[tuple[float, float]]) -> bool:
    """A fix at t (s) falls in an outage: from its start to its end, both included (a fix
    at the very end would reach the aiding before the end's heading is scored)."""
    return any(a <= t <= b for a, b in windows)


def _block(prep: PreparedDrive, i: int) -> Block:
    """Step i of a prepared drive as the closed block the daemon's stepper takes: its raw mean
    (u + the static bias), samples, spread and temperature."""
    s = prep.steps
    raw = float(s.u[i]) + s.bias_dps
    n = int(s.n_samples[i])
    sd = 0.0 if s.omega_std is None else float(s.omega_std[i])
    temp = None if s.temp_c is None or math.isnan(s.temp_c[i]) else float(s.temp_c[i])
    t = float(s.t_end[i])
    return Block(i, t - s.T, t, raw, n, temp, 0, n * (sd * sd + raw * raw))


def _aided_run(
    prep: PreparedDrive,
    config: PipelineConfig,
    fix_t: FloatArray,
    fixes: Sequence[LogFix],
    windows: Sequence[tuple[float, float]],
    aiding_config: AidingConfig,
) -> tuple[FloatArray, FloatArray, int]:
    """The published heading (compass deg, NaN before the first alignment) and its sd (deg,
    NaN where the method publishes none) at each step end of one method through the daemon's
    stepper and its GPS aiding stage, and the steps aided. The aiding's clock is the log's (s
    since its first sample)."""
    s = prep.steps
    aiding = GpsAiding(aiding_config)
    stepper = Stepper(config, aiding)
    n = s.u.shape[0]
    heading = np.full(n, math.nan)
    sd = np.full(n, math.nan)
    j, aided, t_prev = 0, 0, -math.inf
    for i in range(n):
        t = float(s.t_end[i])
        while j < len(fixes) and fix_t[j] <= t:
            if not _in_outage(float(fix_t[j]), windows):
                aiding.on_fix(fixes[j], float(fix_t[j]))
            j += 1
        stepper.speed_mps = aiding.speed(t)
        gap = t - t_prev - s.T if t - t_prev > 1.5 * s.T and t_prev > -math.inf else 0.0
        t_prev = t
        msg = stepper.message(_block(prep, i), i, t, 0, None, gap)
        if "heading_offset" in msg:
            heading[i] = float(msg["heading"])
        if "heading_sd" in msg:
            sd[i] = float(msg["heading_sd"])
        aided += msg.get("mode") == "aided"
    return heading, sd, aided


def run_outages(
    prep: PreparedDrive,
    log: DriveLog,
    spec: OutageSpec,
    methods: Sequence[str] = (FROZEN, "hdr", "hdr+"),
    setup: MethodSetup = DEFAULTS,
    aiding_config: AidingConfig | None = None,
    phase_s: float = 0.0,
) -> OutageResult:
    """Each method's heading error at the end of each outage of a drive (module docstring).

    prep: the drive prepared from ``log`` (its steps and truth at step ends). setup: the
    methods' setup, as ``hdrd evaluate`` has it (the drive's calibration, or the bias given,
    and its output step are added here). aiding_config: the aiding's
    thresholds (default: the daemon's, with the drive's step period). phase_s: the grid of
    outages starts this much later, s (:func:`outage_windows`). EvaluationError when the
    drive has no outage, or no fix to aid from."""
    s = prep.steps
    if s.u.shape[0] == 0:
        raise EvaluationError(f"{prep.name}: no steps to evaluate")
    start = prep.start_s
    end = float(s.t_end[-1])
    windows = outage_windows(spec, start, end, phase_s)
    if not windows:
        raise EvaluationError(
            f"{prep.name}: {(end - start) / 60.0:.1f} min after calibration hold no outage of "
            f"{spec} (the first ends {spec.period_s:g} s in)"
        )
    fix_t, fixes = drive_fixes(log)
    if not fixes:
        raise EvaluationError(f"{prep.name}: no fix to aid the heading from")
    cfg = aiding_config or AidingConfig(step_s=s.T)
    ends = [int(np.searchsorted(s.t_end, b, side="right")) - 1 for _, b in windows]
    errors: dict[str, FloatArray] = {}
    aided: dict[str, int] = {}
    q = prep.quant_step_dps if prep.quant_step_dps > 0 else None
    bias = prep.bias if prep.bias is not None else BiasRecord.given(s.bias_dps)
    trace = _trace_start(prep, windows)
    for m in methods:
        config = PipelineConfig(setup=replace(setup, method=m, bias=bias, quant_step_dps=q))
        heading, sd, aided[m] = _aided_run(prep, config, fix_t, fixes, windows, cfg)
        e = np.full(len(windows), math.nan)
        for k, i in enumerate(ends):
            if i >= 0 and math.isfinite(prep.truth[i]) and math.isfinite(heading[i]):
                e[k] = wrap180(float(heading[i]) - float(prep.truth[i]))
        errors[m] = e
        trace[f"heading_{_TRACE_NAME.get(m, m)}"] = heading
        if np.isfinite(sd).any():
            trace[f"heading_sd_{m}"] = sd
    return OutageResult(prep.name, spec, tuple(windows), tuple(methods), errors, aided, trace)


def _trace_start(
    prep: PreparedDrive, windows: Sequence[tuple[float, float]]
) -> dict[str, FloatArray]:
    """The outage trace's first columns: ``t``, ``in_outage`` (1 inside [start, end)),
    ``heading_truth``."""
    s = prep.steps
    inside = np.array([any(a <= t < b for a, b in windows) for t in s.t_end.tolist()])
    return {"t": s.t_end, "in_outage": inside.astype(np.float64), "heading_truth": prep.truth}


_TRACE_NAME = {FROZEN: "frozen"}
"""A method's name in the outage trace's columns (``none`` through the aiding is the frozen
bias)."""


def _label(method: str) -> str:
    return "frozen bias" if method == FROZEN else method


def pooled(runs: Sequence[OutageResult], method: str) -> tuple[float, int]:
    """(mean |error| over every scored outage of every drive, deg; how many outages)."""
    e = np.concatenate([np.abs(r.errors[method]) for r in runs]) if runs else np.empty(0)
    e = e[np.isfinite(e)]
    return (float(np.mean(e)) if e.shape[0] else math.nan), int(e.shape[0])


def format_outages(runs: Sequence[OutageResult]) -> str:
    """The outage table: per drive the outages scored and each method's mean |error| at
    their ends (deg), and the mean over all outages."""
    if not runs:
        return ""
    ms = runs[0].methods
    name_w = max(12, *(len(r.name) for r in runs))
    head = f"{'drive':<{name_w}} {'outages':>8}" + "".join(f" {_label(m):>12}" for m in ms)
    lines = [
        f"GNSS outages of {runs[0].spec.duration_s:g} s at the end of every "
        f"{runs[0].spec.period_s:g} s: mean |heading error| at their ends, deg",
        head,
        "-" * len(head),
    ]
    for r in runs:
        line = f"{r.name:<{name_w}} {f'{r.scored}/{len(r.windows)}':>8}"
        lines.append(line + "".join(f" {_num(r.mean_abs(m)):>12}" for m in ms))
    lines.append("-" * len(head))
    n = pooled(runs, ms[0])[1]
    line = f"{'all outages':<{name_w}} {n:>8}"
    lines.append(line + "".join(f" {_num(pooled(runs, m)[0]):>12}" for m in ms))
    lines.append(
        "frozen bias: GPS aiding, the static bias it learned frozen at the outage's start "
        "(no drift reduction); each method through the daemon's aiding path"
    )
    return "\n".join(lines)


def _num(v: float) -> str:
    return f"{v:.2f}" if math.isfinite(v) else "-"


def outages_json(runs: Sequence[OutageResult]) -> dict[str, Any]:
    """The outages for ``--json``: the spec, per drive each outage's window and each method's
    error at its end (deg; null where unscored) and their mean |error|, and the mean over
    all outages (keys by method name; ``none`` is the frozen-bias baseline)."""

    def num(v: float) -> float | None:
        return float(v) if math.isfinite(v) else None

    ms = runs[0].methods
    drives = []
    for r in runs:
        d: dict[str, Any] = {"name": r.name, "windows": [[a, b] for a, b in r.windows]}
        for m in ms:
            d[f"errors_{m}"] = [num(float(v)) for v in r.errors[m]]
            d[f"mean_abs_{m}"] = num(r.mean_abs(m))
        drives.append(d)
    mean = {f"mean_abs_{m}": num(pooled(runs, m)[0]) for m in ms}
    mean["outages"] = pooled(runs, ms[0])[1]
    return {
        "duration_s": runs[0].spec.duration_s,
        "period_s": runs[0].spec.period_s,
        "drives": drives,
        "mean": mean,
    }
