"""Evaluation against ground truth: the paper's Table II for any drive logs.

Pure core (:func:`prepare_drive`, :func:`evaluate_prepared`, :func:`evaluate_drive`,
:func:`summarize`, :func:`to_json`, :func:`format_table`) and the reading of drive logs
(:func:`load_drives`); the ``hdrd evaluate`` command is :mod:`hdrd.commands.evaluate`.
docs/evaluation.md describes the method in full.

How a drive log becomes Table II numbers:

1. The log goes through the daemon's own block code and per-block stepper
   (:mod:`hdrd.analysis.prepare`): blocks of T by sample time (Eq. 11), the static bias eps0
   measured per drive as the daemon's start-up window would (or given), u_i = block mean -
   eps0 (Eq. 2) per step. A step without samples is no step: the yaw holds, it is not scored.
2. Each method (:mod:`hdrd.core.methods`: ``none``, static bias only; ``hdr``, the paper; ``hdr+``)
   runs its batch form over those steps from yaw 0 at the drive's start, with its settings
   derived as the daemon derives them (HDR+: :func:`hdrd.core.methods.plus_settings`, from the
   samples per step and the calibration record), giving the yaw at each step's end. The batch
   forms are bit-identical to the steps the daemon takes, so ``hdrd replay`` of the same
   samples publishes the same yaw at every step.
3. The truth heading is sampled at those step ends (:func:`hdrd.analysis.metrics.truth_at`,
   interpolating between fixes at most 2 s apart), the yaw is aligned to the truth at the
   first step end where truth exists, and Eψ (Eq. 12) is the mean |error| over the step ends
   where truth exists.
4. Td, the drive's duration in minutes for NEψ (Eq. 13), is the time from the drive's start
   (the end of the calibration window; the log's start when the bias is given) to the end of
   its last step.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.metrics import e_psi, gyro_heading, improvement, ne_psi
from hdrd.analysis.outages import OutageResult, outages_json
from hdrd.analysis.prepare import (
    DEFAULT_LIMITS,
    DEFAULTS,
    TRUTH_MAX_GAP_S,
    EvaluationError,
    PreparedDrive,
    method_settings,
    prepare_drive,
)
from hdrd.analysis.signcheck import sign_warning
from hdrd.core import methods as registry
from hdrd.core.calibrate import CalibrationLimits
from hdrd.core.methods import MethodSetup, StepInputs
from hdrd.errors import clipped
from hdrd.io.files.access import printable, shown_path
from hdrd.io.files.drivecolumns import DEFAULT_READ_LIMITS, DriveLogError, ReadLimits
from hdrd.io.files.drivefiles import DriveRef, find_drives
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "DriveResult",
    "EvaluationError",
    "PreparedDrive",
    "StepInputs",
    "drive_paths",
    "drive_refs",
    "evaluate_drive",
    "evaluate_logs",
    "evaluate_prepared",
    "evaluated_methods",
    "format_table",
    "load_drives",
    "method_key",
    "method_settings",
    "method_yaw",
    "plus_model",
    "prepare_drive",
    "read_ref",
    "summarize",
    "to_json",
    "trace_columns",
    "trace_csv",
    "TRACE_METHODS",
]

FloatArray = npt.NDArray[np.float64]


def method_key(method: str) -> str:
    """The suffix of a method's JSON keys: ``none`` -> ``raw`` (Table II's "without HDR")."""
    return "raw" if method == "none" else method


@dataclass(frozen=True)
class DriveResult:
    """Table II's row for one drive, plus the traces the plots draw.

    e_psi, ne_psi: Eψ (deg) and NEψ (deg/min) per method name. improvement: Eψ(none) /
    Eψ(primary), the primary method being the last one evaluated. heading: the aligned gyro
    heading per method, deg CW, continuous (not wrapped), at each step end. bias_source: where
    the static bias came from (given, the first S s, the log's lead-in, a standstill found from
    the speed or the gyro). warnings: what looks wrong with the drive's data, one line each
    (a rate whose sign or unit does not follow the truth: :mod:`hdrd.analysis.signcheck`).
    """

    name: str
    duration_min: float
    bias_dps: float
    bias_source: str
    n_steps: int
    n_compared: int
    missing_steps: int
    methods: tuple[str, ...]
    e_psi: dict[str, float]
    ne_psi: dict[str, float]
    t_end: FloatArray = field(repr=False)
    truth: FloatArray = field(repr=False)
    heading: dict[str, FloatArray] = field(repr=False)
    warnings: tuple[str, ...] = ()
    plus_model: str | None = None
    """With ``hdr+`` evaluated: the error model its settings were fitted to
    (:func:`plus_model`)."""
    outages: OutageResult | None = None
    """With ``--outages``: each method's heading error at the end of each GNSS outage
    (:mod:`hdrd.analysis.outages`)."""
    trace: dict[str, FloatArray] | None = field(default=None, repr=False)
    """With ``--trace``: one value per step, :func:`trace_columns`."""

    @property
    def primary(self) -> str:
        return self.methods[-1]

    @property
    def improvement(self) -> float:
        return improvement(self.e_psi["none"], self.e_psi[self.primary])

    def improvement_of(self, method: str) -> float:
        return improvement(self.e_psi["none"], self.e_psi[method])


def evaluated_methods(methods: Sequence[str]) -> tuple[str, ...]:
    """The methods to evaluate, ``none`` first (every result is against it), each once;
    EvaluationError naming one that is not registered."""
    out = ["none"] + [m for m in methods if m != "none"]
    unknown = [m for m in out if m not in registry.REGISTRY]
    if unknown:
        raise EvaluationError(
            f"method {unknown[0]!r} is not available (available: {', '.join(registry.names())})"
        )
    return tuple(dict.fromkeys(out))


def method_yaw(prep: PreparedDrive, method: str, setup: MethodSetup = DEFAULTS) -> FloatArray:
    """Yaw (deg CCW since the drive's start) at each step end of one method on a prepared
    drive: its batch form with its settings derived as the daemon derives them from the setup
    (:func:`hdrd.config.method_setup`: ``hdr.*``, the gyro's error model, ``standstill.*``;
    HDR+'s base) and the drive (:func:`hdrd.analysis.prepare.method_settings`). The output
    step is the log's own (its lattice), as the daemon knows its ADC's."""
    m = registry.get(method)
    return m.batch(prep.steps, method_settings(prep, method, setup))


PLUS = "hdr+"


def plus_model(prep: PreparedDrive, setup: MethodSetup = DEFAULTS) -> str:
    """The error model HDR+'s settings were fitted to on this drive (``PlusParams.model``:
    ``defaults``, ``calibration``, ``grade NAME``, ``recorded``, ``config``)."""
    return str(getattr(method_settings(prep, PLUS, setup), "model", ""))


def evaluate_prepared(
    prep: PreparedDrive,
    methods: Sequence[str] = ("none", "hdr"),
    setup: MethodSetup = DEFAULTS,
) -> DriveResult:
    """Eψ and NEψ of each method on a prepared drive. ``none`` is always evaluated (first).
    ``setup``: the methods' setup (default: the built-in configuration's;
    :func:`hdrd.config.method_setup`), each method's settings derived from it."""
    ms = evaluated_methods(methods)
    T = setup.hdr.T
    if T != prep.steps.T:
        raise EvaluationError(
            f"{prep.name}: hdr.T = {T} s but the drive was stepped at {prep.steps.T} s"
        )
    e: dict[str, float] = {}
    ne: dict[str, float] = {}
    heading: dict[str, FloatArray] = {}
    for m in ms:
        yaw = method_yaw(prep, m, setup)
        e[m] = float(e_psi(yaw, prep.truth, prep.k, prep.align_n))
        ne[m] = float(ne_psi(e[m], prep.duration_min))
        if not (math.isfinite(e[m]) and math.isfinite(ne[m])):
            raise EvaluationError(
                f"{prep.name}: {m} gives a heading error of {e[m]!r} deg over "
                f"{prep.duration_min!r} min, not a number to report"
            )
        heading[m] = gyro_heading(yaw, prep.truth, prep.k, prep.align_n)
    return DriveResult(
        name=prep.name,
        duration_min=prep.duration_min,
        bias_dps=prep.steps.bias_dps,
        bias_source=prep.bias_source,
        n_steps=int(prep.steps.u.shape[0]),
        n_compared=int(np.count_nonzero(np.isfinite(prep.truth))),
        missing_steps=prep.missing_steps,
        methods=ms,
        e_psi=e,
        ne_psi=ne,
        t_end=prep.steps.t_end,
        truth=prep.truth,
        heading=heading,
        warnings=tuple(w for w in (sign_warning(prep.name, prep.sign),) if w is not None),
        plus_model=plus_model(prep, setup) if PLUS in ms else None,
    )


TRACE_METHODS = ("none", "hdr", "hdr+")
"""The methods whose heading ``--trace`` writes, whatever ``--method`` asks."""


def trace_columns(prep: PreparedDrive, setup: MethodSetup = DEFAULTS) -> dict[str, FloatArray]:
    """A drive's trace, one value per step (``hdrd evaluate --trace``): ``t`` (s, the step's
    end, since the log's first sample), ``heading_truth`` (compass deg; NaN where unknown),
    ``speed`` (m/s, the step's mean; NaN where unknown) and ``heading_<m>`` for each of
    :data:`TRACE_METHODS`: its compass heading in [0, 360), aligned as Eψ aligns it
    (:func:`hdrd.analysis.prepare.alignment`), as the daemon would have published it had it
    been given that heading at the start; and ``heading_sd_<m>`` (deg, 1 sigma) for each that
    estimates its uncertainty (HDR+)."""
    s = prep.steps
    n = s.u.shape[0]
    cols: dict[str, FloatArray] = {
        "t": s.t_end,
        "heading_truth": prep.truth,
        "speed": s.speed if s.speed is not None else np.full(n, math.nan),
    }
    for m in TRACE_METHODS:
        yaw = method_yaw(prep, m, setup)
        cols[f"heading_{m}"] = np.mod(gyro_heading(yaw, prep.truth, prep.k, prep.align_n), 360.0)
    for m in TRACE_METHODS:
        sd = registry.get(m).heading_sd(prep.steps, method_settings(prep, m, setup))
        if sd is not None:
            cols[f"heading_sd_{m}"] = sd
    return cols


def trace_csv(cols: dict[str, FloatArray]) -> str:
    """A trace as CSV text: a header of the column names, a row per step, an empty cell
    where a value is unknown."""

    def cell(v: float, digits: int) -> str:
        return f"{v:.{digits}f}" if math.isfinite(v) else ""

    names = list(cols)
    digits = [3 if k == "t" else 0 if k in FLAG_COLUMNS else 4 for k in names]
    lines = [",".join(names)]
    for i in range(cols["t"].shape[0]):
        lines.append(",".join(cell(float(cols[k][i]), d) for k, d in zip(names, digits)))
    return "\n".join(lines) + "\n"


FLAG_COLUMNS = frozenset({"in_outage"})
"""Trace columns of 0 and 1, written as such."""


def evaluate_drive(
    log: DriveLog,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    methods: Sequence[str] = ("none", "hdr"),
    setup: MethodSetup = DEFAULTS,
) -> DriveResult:
    """Table II's row for one drive log: Eψ (Eq. 12) and NEψ (Eq. 13) per method.

    bias: static bias eps0, deg/s; None = measured per drive (``calibrate_seconds``, else
    the log's lead-in, else a standstill found in it; EvaluationError if there is none).
    """
    prep = prepare_drive(log, bias, calibrate_seconds, setup.hdr.T)
    return evaluate_prepared(prep, methods, setup)


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.shape[0] == 0:
        return math.nan, math.nan
    mean = float(np.mean(a))
    # The paper's sigma of the nine improvements (7.57) is the sample standard deviation.
    std = float(np.std(a, ddof=1)) if a.shape[0] > 1 else math.nan
    return mean, std


@dataclass(frozen=True)
class Summary:
    """The "average of all drives" row: means over drives, as the paper's bottom line.

    improvement_std: sample standard deviation of the per-drive improvements (paper: σ).
    """

    n: int
    duration_min: float
    total_min: float
    e_psi: dict[str, float]
    ne_psi: dict[str, float]
    improvement: float
    improvement_std: float
    improvement_of: dict[str, tuple[float, float]]


def summarize(results: Sequence[DriveResult]) -> Summary:
    """Mean Eψ, mean NEψ per method, and the mean (and σ) of the per-drive improvements."""
    if not results:
        raise ValueError("no drives to summarize")
    ms = results[0].methods
    e = {m: float(np.mean([r.e_psi[m] for r in results])) for m in ms}
    ne = {m: float(np.mean([r.ne_psi[m] for r in results])) for m in ms}
    imp_of = {m: _mean_std([r.improvement_of(m) for r in results]) for m in ms}
    imp, std = imp_of[ms[-1]]
    durations = [r.duration_min for r in results]
    return Summary(
        len(results), float(np.mean(durations)), float(np.sum(durations)), e, ne, imp, std, imp_of
    )


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def to_json(results: Sequence[DriveResult]) -> dict[str, Any]:
    """``{"drives": [{"name", "duration_min", "E_psi_raw", "E_psi_<m>", "NE_psi_raw",
    "NE_psi_<m>", "improvement"}], "mean": {same keys except name}}``.

    With the default methods (none, hdr) the keys are the original ones:
    E_psi_raw, E_psi_hdr, NE_psi_raw, NE_psi_hdr. With ``--method none`` alone, E_psi_none and
    NE_psi_none repeat the raw values (keys E_psi_<method> name each method). ``improvement`` is Eψ(raw) / Eψ(primary
    method); when more than one method besides ``none`` is evaluated, ``improvement_<m>`` is
    added for each. Non-finite numbers (an improvement over a zero error) are null. The mean
    row's duration_min is the mean duration. A drive whose data looks wrong has
    ``warnings``, one line each.
    """
    summary = summarize(results)
    ms = results[0].methods
    extra = [m for m in ms if m != "none"]

    drives = [_json_row(r, summary, ms, extra) for r in results]
    doc: dict[str, Any] = {"drives": drives, "mean": _json_row(None, summary, ms, extra)}
    runs = [r.outages for r in results if r.outages is not None]
    if runs:
        doc["outages"] = outages_json(runs)
    return doc


def _json_row(
    r: DriveResult | None, summary: Summary, ms: Sequence[str], extra: list[str]
) -> dict[str, Any]:
    """One drive's row of :func:`to_json`, or the mean row (``r`` None)."""
    d: dict[str, Any] = {}
    if r is not None:
        d["name"] = r.name
    d["duration_min"] = _num(r.duration_min if r else summary.duration_min)
    for m in ms:
        d[f"E_psi_{method_key(m)}"] = _num(r.e_psi[m] if r else summary.e_psi[m])
    for m in ms:
        d[f"NE_psi_{method_key(m)}"] = _num(r.ne_psi[m] if r else summary.ne_psi[m])
    if list(ms) == ["none"]:  # --method none: the E_psi_<method> spelling too
        d["E_psi_none"], d["NE_psi_none"] = d["E_psi_raw"], d["NE_psi_raw"]
    if r is not None:
        _drive_notes(d, r)
    d["improvement"] = _num(r.improvement if r else summary.improvement)
    if len(extra) > 1:
        for m in extra:
            d[f"improvement_{m}"] = _num(r.improvement_of(m) if r else summary.improvement_of[m][0])
    return d


def _drive_notes(d: dict[str, Any], r: DriveResult) -> None:
    """Add a drive's HDR+ model and its warnings, when it has them, to its row."""
    if r.plus_model is not None:
        d["plus_model"] = r.plus_model
    if r.warnings:
        d["warnings"] = list(r.warnings)


def _fmt(v: float, digits: int) -> str:
    return f"{v:.{digits}f}" if math.isfinite(v) else ("inf" if v == math.inf else "-")


def format_table(results: Sequence[DriveResult]) -> str:
    """A Table II-like text table: one row per drive and the mean row (improvement with σ)."""
    ms = results[0].methods
    name_w = max(12, *(len(r.name) for r in results))
    head = f"{'drive':<{name_w}} {'min':>6} {'bias dps':>9}"
    for m in ms:
        head += f" {'Epsi ' + method_key(m):>10}"
    for m in ms:
        head += f" {'NEpsi ' + method_key(m):>11}"
    head += f" {'improvement':>12}  bias from"
    lines = [head, "-" * len(head)]
    for r in results:
        line = f"{r.name:<{name_w}} {r.duration_min:>6.1f} {r.bias_dps:>9.4f}"
        for m in ms:
            line += f" {_fmt(r.e_psi[m], 2):>10}"
        for m in ms:
            line += f" {_fmt(r.ne_psi[m], 3):>11}"
        line += f" {_fmt(r.improvement, 1) + 'x':>12}  {r.bias_source}"
        lines.append(line)
    s = summarize(results)
    lines.append("-" * len(head))
    line = f"{'mean (' + str(s.n) + ')':<{name_w}} {s.duration_min:>6.1f} {'':>9}"
    for m in ms:
        line += f" {_fmt(s.e_psi[m], 2):>10}"
    for m in ms:
        line += f" {_fmt(s.ne_psi[m], 3):>11}"
    line += f" {_fmt(s.improvement, 1) + 'x':>12}"
    if math.isfinite(s.improvement_std):
        line += f" (σ {s.improvement_std:.2f})"
    lines.append(line)
    lines.append(
        f"total duration {s.total_min:.1f} min ({s.total_min / 60:.2f} h); "
        f"improvement = Epsi raw / Epsi {method_key(ms[-1])}; Epsi in deg, NEpsi in deg/min"
    )
    models = Counter(r.plus_model for r in results if r.plus_model is not None)
    if models:
        if len(models) == 1:
            named = next(iter(models))
        else:
            named = ", ".join(f"{m} ({k} drives)" for m, k in sorted(models.items()))
        lines.append(f'hdr+ error model: {named} (docs/hdrplus.md, "Configuration")')
    return "\n".join(lines)


# -- reading drive logs ------------------------------------------------------------------


YAML_SUFFIXES = (".yaml", ".yml")


def drive_refs(
    paths: Sequence[str],
    notes: list[str] | None = None,
    *,
    strict: bool = False,
    yaml_option: str | None = None,
) -> list[DriveRef]:
    """The drives named (:func:`hdrd.io.files.drivefiles.find_drives`: files, directories, globs; CSV
    or Parquet), in order, each once. EvaluationError for a missing path, a directory without
    logs, or a YAML file (a configuration or a model given where a drive goes: the message
    asks whether ``yaml_option`` was meant). What was left out is added to ``notes``: what a
    directory's scan could not read (with ``strict``: EvaluationError), and a drive named
    more than once (scored once)."""
    for p in paths:
        if p.lower().endswith(YAML_SUFFIXES) and Path(p).is_file():
            hint = f"; did you mean {yaml_option} {p}?" if yaml_option else ""
            raise EvaluationError(
                f"{shown_path(p)}: a YAML file, not a drive log (.csv, .parquet){hint}"
            )
    problems: list[str] = []
    try:
        refs = find_drives(paths, problems)
    except DriveLogError as e:
        raise EvaluationError(str(e)) from None
    if problems and strict:
        raise EvaluationError(problems[0])
    once: dict[tuple[str, Any], DriveRef] = {}
    for r in refs:
        key = (os.path.realpath(r.path), r.key)
        if key in once:
            problems.append(f"{r.name}: named more than once; taken once")
        else:
            once[key] = r
    if notes is not None:
        notes.extend(problems)
    return list(once.values())


def drive_paths(paths: Sequence[str]) -> list[tuple[Path, str]]:
    """Each drive named (:func:`drive_refs`) as (its file or partition directory, its name)."""
    return [(Path(r.path), r.name) for r in drive_refs(paths)]


def read_ref(ref: DriveRef, limits: ReadLimits = DEFAULT_READ_LIMITS) -> DriveLog:
    """Read one drive; EvaluationError with a one-line message if it cannot be read."""
    try:
        return ref.read(limits)
    except FileNotFoundError:
        raise EvaluationError(f"{shown_path(ref.path)}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        why = getattr(e, "strerror", None) or clipped(printable(" ".join(str(e).split())), 200)
        raise EvaluationError(f"{shown_path(ref.path)}: cannot be read: {why}") from None
    except DriveLogError as e:
        raise EvaluationError(str(e)) from None


def load_drives(paths: Sequence[str]) -> list[DriveLog]:
    """Read drive logs (files, directories of them, globs: :func:`drive_refs`); EvaluationError
    with a one-line message on any unreadable file."""
    return [read_ref(r) for r in drive_refs(paths)]


def evaluate_logs(
    logs: Sequence[DriveLog],
    methods: Sequence[str] = ("none", "hdr"),
    setup: MethodSetup = DEFAULTS,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    limits: CalibrationLimits = DEFAULT_LIMITS,
    truth_max_gap_s: float = TRUTH_MAX_GAP_S,
) -> tuple[list[DriveResult], list[str]]:
    """Every drive that can be evaluated, and why each other one cannot (one line each).
    With a single drive, a drive that cannot be evaluated raises EvaluationError instead."""
    results: list[DriveResult] = []
    skipped: list[str] = []
    for log in logs:
        try:
            prep = prepare_drive(log, bias, calibrate_seconds, setup.hdr.T, truth_max_gap_s, limits)
            results.append(evaluate_prepared(prep, methods, setup))
        except EvaluationError as e:
            if len(logs) == 1:
                raise
            skipped.append(str(e))
    return results, skipped
