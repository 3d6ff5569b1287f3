"""``hdrd import``: a user's own CSV as a drive log (:mod:`hdrd.io.files.csvimport` maps the columns,
units and sign), with a warning when the rate's sign disagrees with the truth heading."""

from __future__ import annotations

import argparse
import sys

from hdrd.analysis.signcheck import check_sign, sign_warning
from hdrd.cliconfig import drive_log_outputs_ok, read_limits_from_args
from hdrd.errors import clipped
from hdrd.io.files.access import printable, shown_path
from hdrd.io.files.csvimport import Mapping, import_csv, unit_warnings
from hdrd.io.files.drivecolumns import DriveLogError
from hdrd.io.files.drivefiles import log_format, write_log
from hdrd.io.files.drivelog import DriveLog

__all__ = ["main"]


def main(args: argparse.Namespace) -> int:
    """``hdrd import SOURCE.csv --out DRIVE.csv --t COL --omega COL [...]``: exit 0, or 1 with
    one line on stderr (a source that cannot be read or converted, an output that cannot be
    written)."""

    fmt = log_format(args.out, getattr(args, "format", None))
    say = lambda msg: print(f"hdrd import: error: {msg}", file=sys.stderr)  # noqa: E731
    if not drive_log_outputs_ok(args, say, fmt == "dataset"):  # said before the work
        return 1
    mapping = Mapping(
        t=args.t,
        omega=args.omega,
        heading=args.heading,
        speed=args.speed,
        temp=args.temp,
        time_unit=args.time_unit,
        omega_unit=args.omega_unit,
        omega_sign=args.omega_sign,
        heading_unit=args.heading_unit,
        heading_ref=args.heading_ref,
        speed_unit=args.speed_unit,
    )
    try:
        log = import_csv(args.source, mapping, args.delimiter, read_limits_from_args(args))
    except DriveLogError as e:
        print(f"hdrd import: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(
            f"hdrd import: error: cannot read {shown_path(args.source)}: {e.strerror or e}",
            file=sys.stderr,
        )
        return 1
    for unit in unit_warnings(log, mapping):
        print(f"hdrd import: warning: {clipped(printable(unit), 300)}", file=sys.stderr)
    _warn_of_the_sign(log, mapping)
    try:
        written = write_log(args.out, log, fmt, log.name)
    except (OSError, DriveLogError) as e:
        why = (e.strerror if isinstance(e, OSError) else None) or e
        print(f"hdrd import: error: cannot write {printable(args.out)}: {why}", file=sys.stderr)
        return 1
    print(
        f"{len(log)} rows, {log.duration_s:.1f} s ({', '.join(log.columns())}) -> {written}",
        file=sys.stderr,
    )
    return 0


def _warn_of_the_sign(log: DriveLog, mapping: Mapping) -> None:
    """A warning on stderr when the rate's sign disagrees with the truth heading's turns."""
    if log.heading_truth is None:
        return
    check = check_sign(log.t, log.omega, log.heading_truth)
    warning = sign_warning(log.name, check)
    if warning is None:
        return
    hint = (
        "; --omega-sign cw flips it"
        if mapping.omega_sign == "ccw"
        else "; --omega-sign ccw keeps it"
    )
    if not check.flipped:
        hint = " (--omega-unit)"
    print(f"hdrd import: warning: {warning}{hint}", file=sys.stderr)
