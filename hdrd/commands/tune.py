"""``hdrd tune``: the command-line edge of :mod:`hdrd.analysis.tune` (the report, the config
snippet, the JSON), in this process or, with ``--workers`` / ``--scheduler``, on a Dask
cluster (:func:`hdrd.analysis.fleet_jobs.tune_fleet`: the same result)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from hdrd.analysis.cluster import FleetError
from hdrd.analysis.evaluate import (
    EvaluationError,
    PreparedDrive,
    drive_refs,
)
from hdrd.analysis.fleet import open_runner
from hdrd.analysis.fleet_jobs import PrepareJob, read_prepared, tune_fleet
from hdrd.analysis.prepare import PAPER_PARAMS
from hdrd.analysis.progress import ProgressBar
from hdrd.analysis.tune import (
    Interrupted,
    TuneResult,
    check_held_out,
    content_key,
    format_report,
    interrupted_json,
    params_yaml,
    to_json,
    tune,
)
from hdrd.cliconfig import outputs_ok, read_limits_from_args, where_from_args
from hdrd.io.files.access import atomic_write_json, atomic_write_text, shown_path
from hdrd.io.files.drivefiles import DriveRef

__all__ = ["NAMES_IN_COMMENT", "main"]

NAMES_IN_COMMENT = 20
"""Training drives named in the config snippet's comment (a fleet's are counted)."""


def _err(msg: str) -> None:
    print(f"hdrd tune: error: {msg}", file=sys.stderr)


def _prepared(
    refs: Sequence[DriveRef], job: PrepareJob, strict: bool, skipped: list[str]
) -> list[PreparedDrive]:
    """Each drive read and prepared (:func:`hdrd.analysis.fleet_jobs.read_prepared`); why each
    other one cannot be is added to ``skipped`` (``strict``: EvaluationError at the first)."""
    out: list[PreparedDrive] = []
    for r in refs:
        d = read_prepared(r, job)
        if isinstance(d, str):
            if strict:
                raise EvaluationError(d)
            skipped.append(d)
        else:
            out.append(d)
    return out


def _run(args: argparse.Namespace, bar: ProgressBar | None, skipped: list[str]) -> TuneResult:

    strict = bool(getattr(args, "strict", False))
    notes: list[str] = []
    train_refs = drive_refs(args.train, notes, strict=strict)
    test_refs = drive_refs(args.test or [], notes, strict=strict)
    for note in notes:
        print(f"hdrd tune: warning: {note}", file=sys.stderr)
    where = where_from_args(args, "hdrd tune")
    if not where.cluster:
        job = PrepareJob(None, args.calibrate_seconds, read_limits=read_limits_from_args(args))
        train = _prepared(train_refs, job, strict, skipped)
        test = _prepared(test_refs, job, strict, skipped)
        check_held_out(*([(d.name, content_key(d)) for d in part] for part in (train, test)))
        if not train:
            raise EvaluationError(
                skipped.pop(0)
                if len(train_refs) == 1
                else f"none of the {len(train_refs)} training drives can be used"
            )
        return tune(
            train,
            test,
            args.candidates,
            args.seed,
            calibrate_seconds=args.calibrate_seconds,
            progress=bar,
        )
    with open_runner(where) as runner:
        return tune_fleet(
            runner,
            train_refs,
            test_refs,
            args.candidates,
            args.seed,
            calibrate_seconds=args.calibrate_seconds,
            progress=bar,
            strict=strict,
            skipped=skipped,
            read_limits=read_limits_from_args(args),
        )


def _comment(result: TuneResult, seed: int) -> list[str]:
    names = [d.name for d in result.train["baseline"]]
    n_test = len(result.test["baseline"])
    shown = ", ".join(names[:NAMES_IN_COMMENT])
    if len(names) > NAMES_IN_COMMENT:
        shown += f", and {len(names) - NAMES_IN_COMMENT} more"
    s_tr = result.summary("train", "tuned")
    s_te = result.summary("test", "tuned")
    comment = [
        f"HDR parameters tuned by `hdrd tune` (seed {seed}, {result.n_evaluated} sets) on "
        f"{len(names)} training drive(s): " + shown,
        f"training: mean NEpsi {s_tr.ne_psi['hdr']:.3f} deg/min, {s_tr.improvement:.2f}x"
        if s_tr
        else "",
        (
            f"test: mean NEpsi {s_te.ne_psi['hdr']:.3f} deg/min, {s_te.improvement:.2f}x "
            f"on {n_test} drive(s)"
        )
        if s_te
        else "no test drives",
        "paste into /etc/hdrd/hdrd.yaml (replacing its hdr: section)",
    ]
    return [c for c in comment if c]


def _interrupted(args: argparse.Namespace, e: Interrupted) -> int:
    """Ctrl-C: the best set so far on stdout (and in --out, --json), said in one line on
    stderr; exit 130. The set is not checked on the test drives."""
    best = e.best(PAPER_PARAMS)
    if best is None:
        print("hdrd tune: interrupted before any parameter set was scored", file=sys.stderr)
        return 130
    n = e.scored.shape[0]
    what = (
        f"the best of the first {n} of {args.candidates} parameter sets (seed {args.seed}): "
        f"mean training NEpsi {best[1]:.3f} deg/min, not checked on the test drives"
    )
    snippet = params_yaml(best[0], [f"HDR parameters from an interrupted `hdrd tune`: {what}"])
    print(snippet, end="")
    written = []
    try:
        if args.out:
            atomic_write_text(args.out, snippet)
            written.append(args.out)
        if args.json:
            atomic_write_json(
                args.json, interrupted_json(e, PAPER_PARAMS, args.seed, args.candidates)
            )
            written.append(args.json)
    except OSError as err:
        _err(f"cannot write {err.filename or ''}: {err.strerror or err}")
    where = f"; written to {' and '.join(written)}" if written else ""
    print(f"hdrd tune: interrupted: {what}{where}", file=sys.stderr)
    return 130


def main(args: argparse.Namespace) -> int:
    """``hdrd tune TRAIN.csv|DIR... --test TEST.csv|DIR... [--candidates N] [--seed S]
    [--calibrate-seconds S] [--out YAML] [--json FILE] [--strict] [--no-progress]
    [--workers N | --scheduler ADDRESS]``."""
    if args.candidates < 1:
        _err(f"--candidates must be >= 1, got {args.candidates}")
        return 2
    if not outputs_ok(args, _err, ("--out", "--json")):  # before the work
        return 1
    bar = None if args.no_progress else ProgressBar(f"tune {args.candidates} sets")
    t0 = time.monotonic()
    skipped: list[str] = []
    try:
        result = _run(args, bar, skipped)
    except (EvaluationError, FleetError, Interrupted) as e:
        if bar is not None:
            bar.close()
        for why in skipped:
            print(f"hdrd tune: skipped {why}", file=sys.stderr)
        if isinstance(e, Interrupted):
            return _interrupted(args, e)
        _err(str(e))
        return 1
    if bar is not None:
        bar.close()
    for why in skipped:
        print(f"hdrd tune: skipped {why}", file=sys.stderr)
    seconds = time.monotonic() - t0
    print(format_report(result, seconds))
    return _write(args, result, seconds)


def _write(args: argparse.Namespace, result: TuneResult, seconds: float) -> int:
    """--out and --json; the exit status."""
    path = args.out
    try:
        if args.out:
            atomic_write_text(args.out, params_yaml(result.best, _comment(result, args.seed)))
        path = args.json
        if args.json:
            atomic_write_json(args.json, to_json(result, seconds))
    except OSError as e:
        _err(f"cannot write {shown_path(path)}: {e.strerror or e}")
        return 1
    return 0
