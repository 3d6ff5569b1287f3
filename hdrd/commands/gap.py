"""The ``hdrd gap`` command: read the logs and the starting model, run (in this process or on a
Dask cluster), print, write."""

from __future__ import annotations

import argparse
import math
import sys
from typing import TYPE_CHECKING

from hdrd.analysis.cluster import FleetError
from hdrd.analysis.evaluate import EvaluationError, drive_refs
from hdrd.analysis.fleet import open_runner
from hdrd.analysis.gap.fleet import GapJob, GapOutputs, gap_fleet, gap_refs
from hdrd.analysis.gap.plots import plot_gap
from hdrd.analysis.plots import plot_to_file
from hdrd.cliconfig import outputs_ok, read_limits_from_args, where_from_args
from hdrd.io.files.access import atomic_write_json, atomic_write_text, shown_path
from hdrd.io.files.drivecolumns import DriveLogError
from hdrd.sim.gyro import DEFAULT_START_MODEL, GyroModel, load_model, save_model

if TYPE_CHECKING:
    from hdrd.analysis.gap.fleet import GapOutcome
    from hdrd.io.files.drivefiles import DriveRef

__all__ = ["main", "parse_period"]


FLEET_OUT = "several drives write a folder of models (OUT/NAME.yaml each)"
"""What ``--out`` is for several drives, said when it names a file."""


def _err(msg: str) -> None:
    print(f"hdrd gap: {msg}", file=sys.stderr)


def parse_period(text: str) -> tuple[float, float]:
    """``T0:T1`` (s) -> (T0, T1); ValueError naming what is wrong."""
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        t0, t1 = float(a), float(b)
    except ValueError:
        raise ValueError(
            f"--exclude {text!r}: expected T0:T1, two times in seconds of the log's t "
            "(e.g. 120:185)"
        ) from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
        raise ValueError(f"--exclude {text!r}: need finite times with T0 <= T1")
    return t0, t1


def main(args: argparse.Namespace) -> int:
    """``hdrd gap MEASURED... [--model MODEL.yaml] [--out FITTED.yaml|DIR] [--report REPORT.json]
    [--gyro-out GYRO.yaml] [--plot FILE.png] [--standstill] [--exclude T0:T1 ...] [--seed N] [--workers N |
    --scheduler ADDRESS] [--no-progress]``. Exit 0 ok, 1 bad input or I/O error, 78 bad
    model file. Several drives (files, directories, globs): each analysed on its own, one line
    each (:mod:`hdrd.analysis.gap.fleet`)."""
    try:
        exclude = [parse_period(x) for x in getattr(args, "exclude", None) or []]
    except ValueError as e:
        _err(str(e))
        return 1

    start = _start_model(args)
    if start is None:
        return 78
    measured = [args.measured] if isinstance(args.measured, str) else list(args.measured)
    refs = _drives(args, measured)
    if refs is None:
        return 1

    flags = ("--report", "--gyro-out", "--plot") + (("--out",) if len(refs) == 1 else ())
    folders = {} if len(refs) == 1 else {"--out": FLEET_OUT}
    if not outputs_ok(args, _err, flags, folders):  # said before the work, not after it
        return 1

    job = GapJob(
        start,
        bool(args.standstill),
        tuple(exclude),
        int(args.seed),
        bool(args.plot),
        read_limits_from_args(args),
    )

    try:
        with open_runner(where_from_args(args, "hdrd gap")) as runner:
            if len(refs) > 1:
                strict = bool(getattr(args, "strict", False))
                progress = not getattr(args, "no_progress", False)
                outputs = GapOutputs(args.out, args.report, strict, progress)
                return gap_fleet(outputs, refs, job, runner)
            one = next(gap_refs(refs, job, runner))
    except (DriveLogError, FleetError) as e:
        _err(str(e))
        return 1
    if one.skipped is not None:
        _err(one.skipped)
        return 1
    print(one.result.summary)
    return _write_files(args, one.result, measured)


def _start_model(args: argparse.Namespace) -> GyroModel | None:
    """The model the fit starts from (--model, else the default); None when it cannot be
    read (why said on stderr)."""
    if not args.model:
        return DEFAULT_START_MODEL
    try:
        return load_model(args.model)
    except OSError as e:
        _err(f"cannot read the model {args.model}: {e.strerror or e}")
    except ValueError as e:
        _err(str(e))
    return None


def _drives(args: argparse.Namespace, measured: list[str]) -> list[DriveRef] | None:
    """The drives named; None when they cannot be found or are too many for --plot or
    --gyro-out, which describe one drive (why said on stderr)."""
    notes: list[str] = []
    try:
        strict = bool(getattr(args, "strict", False))
        refs = drive_refs(measured, notes, strict=strict, yaml_option="--model")
    except EvaluationError as e:
        _err(f"cannot read {e}")
        return None
    for note in notes:
        _err(f"warning: {note}")
    if len(refs) > 1 and args.plot:
        _err(f"--plot draws one drive; {len(refs)} were given")
        return None
    if len(refs) > 1 and getattr(args, "gyro_out", None):
        _err(f"--gyro-out describes one gyro from one drive; {len(refs)} were given")
        return None
    return refs


def _write_files(args: argparse.Namespace, res: GapOutcome, measured: list[str]) -> int:
    """One drive's --report, --out, --gyro-out and --plot; the exit status."""
    gyro_out = getattr(args, "gyro_out", None)
    try:
        if args.report:
            atomic_write_json(args.report, res.report)
        if args.out:
            save_model(res.model, args.out)
        if gyro_out:
            # the name goes into a YAML comment: one printable line, whatever the file is called
            from hdrd.analysis.gap.report import gyro_section

            atomic_write_text(
                gyro_out, gyro_section(res.model, shown_path(measured[0]), res.report)
            )
    except OSError as e:
        _err(f"cannot write: {e.strerror or e}" + (f" ({e.filename})" if e.filename else ""))
        return 1
    if args.plot:
        problem = plot_to_file(lambda path: plot_gap(res.result, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
