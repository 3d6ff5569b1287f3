"""``hdrd simulate``: write a simulated drive log, or the paper-like benchmark, as CSV or
Parquet (docs/drive-format.md).

The command-line edge of :mod:`hdrd.sim` (flags in hdrd/cli.py ``_simulate``)::

    hdrd simulate --drive city --minutes 20 --seed 3 --out drive.csv   # one drive
    hdrd simulate --drive rural --model my-gyro.yaml --out -          # CSV to stdout
    hdrd simulate --benchmark train --out bench/train                  # the nine, DIR/<name>.csv
    hdrd simulate --drive highway --grade tactical --out drive.csv     # a gyro grade preset
    hdrd simulate --drive city --seed 3 --out drive.parquet            # Parquet, one file
    hdrd simulate --drive city --seed 3 --out fleet --format dataset   # fleet/drive=city-3/
    hdrd simulate --benchmark train --errors-from gap.json --out train # real gyros' errors
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from hdrd.cliconfig import drive_log_outputs_ok
from hdrd.core.grades import DEFAULT_GRADE, GRADES, Grade
from hdrd.errors import EX_CONFIG, EX_USAGE
from hdrd.io.files.access import shown_path
from hdrd.io.files.drivecolumns import DriveLogError
from hdrd.io.files.drivefiles import log_format, write_log
from hdrd.io.files.drivelog import write_drive
from hdrd.sim.benchmark import TEST_DRIVES, TRAIN_DRIVES, generate
from hdrd.sim.drive import simulate_drive, too_big
from hdrd.sim.grades import grade_model
from hdrd.sim.gyro import GyroModel, load_model
from hdrd.sim.recordings import FittedErrors, errors_from
from hdrd.sim.vehicle import DRIVE_TYPES

__all__ = ["simulate_main"]


def _err(msg: str) -> None:
    print(f"hdrd simulate: {msg}", file=sys.stderr)


def _why(e: Exception) -> str:
    return (e.strerror if isinstance(e, OSError) else None) or str(e)


def simulate_main(args: argparse.Namespace) -> int:
    """Run ``hdrd simulate``; returns the exit status (0 ok, 1 I/O error, 2 usage, 78 bad model)."""
    model: GyroModel | None = None
    grade = getattr(args, "grade", None)
    if grade is not None and grade not in GRADES:
        _err(f"unknown --grade {grade!r} (known: {', '.join(GRADES)})")
        return EX_USAGE
    if args.hz is None:
        args.hz = Grade.from_table(grade or DEFAULT_GRADE).rate_hz
    if args.model:
        model = _model(args.model)
        if model is None:
            return EX_CONFIG
    if not (math.isfinite(args.hz) and args.hz > 0):
        _err(f"--hz must be > 0, got {args.hz}")
        return EX_USAGE
    too_big = _too_big(args)
    if too_big:
        _err(too_big)
        return EX_USAGE
    ok, errors = _errors(args)
    if not ok:
        return EX_CONFIG
    folder = (
        bool(args.benchmark)
        or log_format(args.out or "-", getattr(args, "format", None)) == "dataset"
    )
    if not drive_log_outputs_ok(args, _err, folder):  # said before the work
        return 1
    if args.benchmark:
        return _benchmark(args, model, grade, errors)
    return _one_drive(args, model, grade, errors)


def _model(path: str) -> GyroModel | None:
    """The gyro model of ``--model``; None when it cannot be read (why said on stderr)."""
    try:
        return load_model(path)
    except OSError as e:
        _err(f"cannot read the model {shown_path(path)}: {e.strerror or e}")
    except ValueError as e:
        _err(str(e))
    return None


def _errors(args: argparse.Namespace) -> tuple[bool, FittedErrors | None]:
    """(True, the gyro errors of ``--errors-from``, None without it); (False, None) when
    they cannot be read (why said on stderr)."""
    if not getattr(args, "errors_from", None):
        return True, None
    try:
        return True, errors_from(args.errors_from)
    except OSError as e:
        _err(f"cannot read {shown_path(args.errors_from)}: {_why(e)}")
    except ValueError as e:
        _err(str(e))
    return False, None


def _one_drive(
    args: argparse.Namespace,
    model: GyroModel | None,
    grade: str | None,
    errors: FittedErrors | None = None,
) -> int:
    """``hdrd simulate --drive``: one drive, to a file or stdout."""
    if args.drive not in DRIVE_TYPES:
        _err(f"unknown --drive {args.drive!r} (known: {', '.join(DRIVE_TYPES)})")
        return EX_USAGE
    if not (math.isfinite(args.minutes) and args.minutes > 0):
        _err(f"--minutes must be > 0, got {args.minutes}")
        return EX_USAGE
    if grade is not None:
        model = grade_model(grade, args.seed)
    drawn = None
    if errors is not None:  # the drive's gyro, drawn by its seed from the real drives' errors
        drawn, model = errors.draw(args.seed)
    log = simulate_drive(args.drive, args.minutes, args.seed, hz=args.hz, model=model)
    if grade is not None:
        log.meta["grade"] = grade
    if errors is not None:
        log.meta["gyro_errors_from"] = f"{drawn} ({errors.source})"
    out = args.out or "-"
    fmt = log_format(out, getattr(args, "format", None))
    if out == "-" and fmt != "csv":
        _err(f"--format {fmt} needs --out (a file, or a directory for a dataset)")
        return EX_USAGE
    try:
        if out == "-":
            write_drive(sys.stdout, log)  # type: ignore[arg-type]
        else:
            out = write_log(out, log, fmt, f"{args.drive}-{args.seed}")
    except BrokenPipeError:
        raise  # the reader went away (`| head`): hdrd.cli ends quietly, status 0
    except (OSError, DriveLogError) as e:
        _err(f"cannot write {out}: {_why(e)}")
        return 1
    if out != "-":
        print(
            f"{out}: {args.drive}, {args.minutes:g} min + {log.meta['lead_in_s']} s standstill, "
            f"{len(log)} samples at {args.hz:g} Hz, seed {args.seed}"
        )
    return 0


def _benchmark(
    args: argparse.Namespace,
    model: GyroModel | None,
    grade: str | None,
    errors: FittedErrors | None = None,
) -> int:
    if not args.out or args.out == "-":
        _err("--benchmark needs --out DIR (a directory for <name>.csv files, or the dataset)")
        return EX_USAGE
    specs = TRAIN_DRIVES if args.benchmark == "train" else TEST_DRIVES
    out = Path(args.out)
    fmt = getattr(args, "format", None) or "csv"
    suffix = {"csv": ".csv", "parquet": ".parquet", "dataset": ""}[fmt]
    try:
        os.makedirs(out, exist_ok=True)
        for spec in specs:
            if grade is not None:
                model = grade_model(grade, spec.seed)
            log = generate(spec, hz=args.hz, model=model, errors=errors)
            if grade is not None:
                log.meta["grade"] = grade
            target = str(out) if fmt == "dataset" else str(out / f"{spec.name}{suffix}")
            path = write_log(target, log, fmt, spec.name, inside=out)  # no link followed
            drawn = log.meta.get("gyro_errors_from")
            print(
                f"{path}: {spec.minutes:g} min, {spec.description}"
                + (f"; gyro: {drawn}" if drawn else "")
            )
    except (OSError, DriveLogError) as e:
        _err(f"cannot write to {out}: {_why(e)}")
        return 1
    return 0


def _too_big(args: argparse.Namespace) -> str | None:
    """Why the drive(s) asked for cannot be made (a seed below 0, too many samples:
    :func:`hdrd.sim.drive.too_big`), or None."""
    if not args.benchmark and args.seed < 0:
        return f"--seed must be >= 0, got {args.seed}"
    specs = TRAIN_DRIVES if args.benchmark == "train" else TEST_DRIVES
    minutes = max(s.minutes for s in specs) if args.benchmark else args.minutes
    what = "the longest benchmark drive" if args.benchmark else "a drive"
    return too_big(minutes, args.hz, what)
