"""The ``hdrd gap`` command: read the log and the starting model, run, print, write."""

from __future__ import annotations

import argparse
import math
import sys

from hdrd.analysis.gap.data import GapError
from hdrd.analysis.gap.report import summary, to_report
from hdrd.analysis.gap.search import run_gap
from hdrd.sim.gyro import DEFAULT_START_MODEL

__all__ = ["main", "parse_period"]


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
    """``hdrd gap MEASURED.csv [--model MODEL.yaml] [--out FITTED.yaml] [--report REPORT.json]
    [--plot FILE.png] [--standstill] [--exclude T0:T1 ...] [--seed N]``. Exit 0 ok, 1 bad
    input or I/O error, 78 bad model file."""
    try:
        exclude = [parse_period(x) for x in getattr(args, "exclude", None) or []]
    except ValueError as e:
        _err(str(e))
        return 1
    from hdrd.drivelog import DriveLogError, read_drive
    from hdrd.sim.gyro import load_model, save_model

    if args.plot:
        from hdrd.analysis.plots import plotting_unavailable

        problem = plotting_unavailable()
        if problem:  # said before the work, not after it
            _err(problem)
            return 1

    start = DEFAULT_START_MODEL
    if args.model:
        try:
            start = load_model(args.model)
        except OSError as e:
            _err(f"cannot read the model {args.model}: {e.strerror or e}")
            return 78
        except ValueError as e:
            _err(str(e))
            return 78
    try:
        log = read_drive(args.measured)
    except OSError as e:
        _err(f"cannot read {args.measured}: {e.strerror or e}")
        return 1
    except DriveLogError as e:
        _err(str(e))
        return 1
    try:
        res = run_gap(
            log, start, standstill=bool(args.standstill), exclude=exclude, seed=int(args.seed)
        )
    except (GapError, ValueError) as e:
        _err(str(e))
        return 1
    print(summary(res))
    try:
        if args.report:
            from hdrd.files import atomic_write_json

            atomic_write_json(args.report, to_report(res))
        if args.out:
            save_model(res.final_model, args.out)
    except OSError as e:
        _err(f"cannot write: {e.strerror or e} ({e.filename or ''})")
        return 1
    if args.plot:
        from hdrd.analysis.gap.plots import plot_gap
        from hdrd.analysis.plots import plot_to_file

        problem = plot_to_file(lambda path: plot_gap(res, path), args.plot)
        if problem:
            _err(problem)
            return 1
    return 0
