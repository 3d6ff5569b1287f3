"""``hdrd evaluate``: the command-line edge of :mod:`hdrd.analysis.evaluate` (the paper's
Table II for drive logs, a JSON file, a plot)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from hdrd.analysis.cluster import FleetError
from hdrd.analysis.evaluate import (
    DriveResult,
    EvaluationError,
    drive_refs,
    evaluated_methods,
    format_table,
    to_json,
    trace_csv,
)
from hdrd.analysis.fleet_jobs import PLOT_PANELS_MAX, EvaluateJob, run_evaluate
from hdrd.analysis.fleet_report import fleet_summary, plot_fleet
from hdrd.analysis.outages import OutageSpec, format_outages
from hdrd.analysis.plots import plot_evaluation, plot_to_file
from hdrd.cliconfig import (
    check_bias_arg,
    config_from_args,
    outputs_ok,
    read_limits_from_args,
    where_from_args,
)
from hdrd.config import Config, ConfigError, method_setup
from hdrd.daemon.pipeline import standstill_limits
from hdrd.errors import EX_CONFIG, EX_USAGE
from hdrd.io.files.access import (
    UnsafeNameError,
    atomic_write_json,
    atomic_write_text,
    path_inside,
    printable,
    shown_path,
)

if TYPE_CHECKING:
    from hdrd.analysis.fleet_jobs import EvaluateJob
    from hdrd.analysis.outages import OutageSpec

__all__ = ["main"]


def _err(msg: str) -> None:
    print(f"hdrd evaluate: error: {msg}", file=sys.stderr)


def main(args: argparse.Namespace) -> int:
    """``hdrd evaluate DRIVE.csv|DRIVE.parquet|DIR|GLOB... [--calibrate-seconds S | --bias DPS]
    [--json FILE] [--plot FILE.png] [--outages SPEC] [--config PATH] [--method METHOD] [--strict]
    [--workers N | --scheduler ADDRESS] [--no-progress]``."""

    try:
        cfg, _ = config_from_args(args)  # --config, and --method over hdr.method
        check_bias_arg(args.bias, cfg)  # as run and replay check it
    except ConfigError as e:
        print(f"hdrd evaluate: {e}", file=sys.stderr)
        return EX_CONFIG
    folders = {"--trace": "--trace writes a folder of traces (DIR/NAME.csv each)"}
    if not outputs_ok(args, _err, ("--json", "--plot"), folders):  # before the work
        return 1
    trace = getattr(args, "trace", None)
    outages = None
    if getattr(args, "outages", None):
        try:
            outages = OutageSpec.parse(args.outages, cfg.hdr.params.T)
        except ValueError as e:
            _err(f"--outages: {e}")
            return EX_USAGE
    try:
        results, skipped, job = _evaluate(args, cfg, outages)
    except (EvaluationError, FleetError) as e:
        _err(str(e))
        return 1
    _print_results(results, len(skipped), outages is not None)
    rc = _write_files(args, results, job.traces)
    return _write_traces(trace, results) if trace is not None and rc == 0 else rc


def _evaluate(
    args: argparse.Namespace, cfg: Config, outages: OutageSpec | None
) -> tuple[list[DriveResult], list[str], EvaluateJob]:
    """The drives' results, why each drive left out was skipped (both said on stderr, with
    each drive's warnings) and the job; EvaluationError when no drive can be evaluated."""

    method = cfg.hdr.method
    # HDR+ is shown beside the paper's HDR it improves on.
    ms = evaluated_methods(["hdr", method] if method == "hdr+" else [method])
    notes: list[str] = []
    strict = bool(getattr(args, "strict", False))
    refs = drive_refs(args.drives, notes, strict=strict, yaml_option="--config")
    for note in notes:
        print(f"hdrd evaluate: warning: {note}", file=sys.stderr)
    job = EvaluateJob(
        ms,
        method_setup(cfg),  # hdr.*, the configured gyro's error model, standstill.*
        args.bias,
        args.calibrate_seconds,
        standstill_limits(cfg),
        traces=bool(args.plot) and len(refs) <= PLOT_PANELS_MAX,
        trace=getattr(args, "trace", None) is not None,
        strict=strict,
        read_limits=read_limits_from_args(args),
        outages=outages,
    )
    # Drive after drive here, or on a cluster (--workers / --scheduler): the same results.
    where = where_from_args(args, "hdrd evaluate")
    say = lambda msg: print(f"hdrd evaluate: note: {msg}", file=sys.stderr)  # noqa: E731
    results, skipped = run_evaluate(where, refs, job, not getattr(args, "no_progress", False), say)
    for why in skipped:
        print(f"hdrd evaluate: skipped {why}", file=sys.stderr)
    for r in results:
        for w in r.warnings:
            print(f"hdrd evaluate: warning: {w}", file=sys.stderr)
    if not results:
        raise EvaluationError(f"none of the {len(refs)} drives can be evaluated")
    return results, skipped, job


def _print_results(results: list[DriveResult], n_skipped: int, outages: bool) -> None:
    """The table; with ``outages``, the outages' table; for a fleet, its summary."""

    print(format_table(results))
    runs = [r.outages for r in results if r.outages is not None]
    if outages:
        print()
        print(format_outages(runs) if runs else "GNSS outages: none could be scored")
    if len(results) > PLOT_PANELS_MAX:
        print(fleet_summary(results, n_skipped))


def _write_traces(folder: str, results: list[DriveResult]) -> int:
    """--trace DIR: DIR/<drive>.csv for each drive (its name from the data, kept inside DIR:
    :func:`hdrd.io.files.access.path_inside`; a name that cannot is said and left out), and with
    --outages DIR/<drive>.outages.csv (the aided run through the outages,
    :class:`hdrd.analysis.outages.OutageResult`'s trace); the exit status."""
    for r in results:
        files = [(".csv", r.trace)]
        if r.outages is not None:
            files.append((".outages.csv", r.outages.trace))
        try:
            for suffix, cols in files:
                if cols is not None:
                    path = path_inside(folder, r.name, suffix)
                    atomic_write_text(path, trace_csv(cols), inside=folder)  # no link followed
        except UnsafeNameError as e:
            print(f"hdrd evaluate: warning: --trace: {e}", file=sys.stderr)
        except OSError as e:
            _err(f"cannot write the trace of {printable(r.name)}: {e.strerror or e}")
            return 1
    print(f"hdrd evaluate: traces in {shown_path(folder)}", file=sys.stderr)
    return 0


def _write_files(args: argparse.Namespace, results: list[DriveResult], traces: bool) -> int:
    """The --json file and the --plot (each drive's traces, or a fleet's NEpsi distribution);
    the exit status."""
    if args.json:
        try:
            atomic_write_json(args.json, to_json(results))
        except OSError as e:
            _err(f"cannot write {shown_path(args.json)}: {e.strerror or e}")
            return 1
    if args.plot:
        draw = plot_evaluation if traces else plot_fleet  # a fleet: NEpsi's distribution
        problem = plot_to_file(lambda path: draw(results, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
