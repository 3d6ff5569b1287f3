"""``hdrd evaluate``: the command-line edge of :mod:`hdrd.analysis.evaluate` (the paper's
Table II for drive logs, a JSON file, a plot)."""

from __future__ import annotations

import argparse
import sys

from hdrd.analysis.evaluate import (
    EvaluationError,
    drive_refs,
    evaluated_methods,
    format_table,
    read_limits,
    to_json,
)
from hdrd.config import ConfigError, load_config, settings_context
from hdrd.daemon.pipeline import standstill_limits
from hdrd.errors import EX_CONFIG, EX_USAGE

__all__ = ["main"]


def _err(msg: str) -> None:
    print(f"hdrd evaluate: error: {msg}", file=sys.stderr)


def main(args: argparse.Namespace) -> int:
    """``hdrd evaluate DRIVE.csv|DRIVE.parquet|DIR|GLOB... [--calibrate-seconds S | --bias DPS]
    [--json FILE] [--plot FILE.png] [--outages SPEC] [--config PATH] [--method METHOD] [--strict]
    [--workers N | --scheduler ADDRESS] [--no-progress]``."""
    from hdrd.analysis.fleet import FleetError
    from hdrd.analysis.fleet_jobs import PLOT_PANELS_MAX, EvaluateJob, run_evaluate
    from hdrd.analysis.fleet_report import fleet_summary, plot_fleet

    try:
        cfg, _ = load_config(args.config)
    except ConfigError as e:
        print(f"hdrd evaluate: {e}", file=sys.stderr)
        return EX_CONFIG
    if args.plot:
        from hdrd.analysis.plots import plotting_unavailable

        problem = plotting_unavailable()
        if problem:  # said before the work, not after it
            _err(problem)
            return 1
    outages = None
    if getattr(args, "outages", None):
        from hdrd.analysis.outages import OutageSpec

        try:
            outages = OutageSpec.parse(args.outages)
        except ValueError as e:
            _err(f"--outages: {e}")
            return EX_USAGE
    method = args.method or cfg.hdr.method
    params = cfg.hdr.params
    try:
        # HDR+ is shown beside the paper's HDR it improves on.
        ms = evaluated_methods(["hdr", method] if method == "hdr+" else [method])
        refs = drive_refs(args.drives)
        job = EvaluateJob(
            params,
            ms,
            settings_context(cfg),  # the configured grade, plus.*, standstill.*
            args.bias,
            args.calibrate_seconds,
            standstill_limits(cfg),
            traces=bool(args.plot) and len(refs) <= PLOT_PANELS_MAX,
            strict=bool(getattr(args, "strict", False)),
            read_limits=read_limits(args),
            outages=outages,
        )
        # Drive after drive here, or on a cluster (--workers / --scheduler): the same results.
        results, skipped = run_evaluate(args, refs, job)
        for why in skipped:
            print(f"hdrd evaluate: skipped {why}", file=sys.stderr)
        for r in results:
            for w in r.warnings:
                print(f"hdrd evaluate: warning: {w}", file=sys.stderr)
        if not results:
            raise EvaluationError(f"none of the {len(refs)} drives can be evaluated")
    except (EvaluationError, FleetError) as e:
        _err(str(e))
        return 1
    print(format_table(results))
    runs = [r.outages for r in results if r.outages is not None]
    if outages is not None:
        from hdrd.analysis.outages import format_outages

        print()
        print(format_outages(runs) if runs else "GNSS outages: none could be scored")
    if len(results) > PLOT_PANELS_MAX:
        print(fleet_summary(results, len(skipped)))
    if args.json:
        try:
            from hdrd.io.files import atomic_write_json

            atomic_write_json(args.json, to_json(results))
        except OSError as e:
            _err(f"cannot write {args.json}: {e.strerror or e}")
            return 1
    if args.plot:
        from hdrd.analysis.plots import plot_evaluation, plot_to_file

        draw = plot_evaluation if job.traces else plot_fleet  # a fleet: NEpsi's distribution
        problem = plot_to_file(lambda path: draw(results, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
