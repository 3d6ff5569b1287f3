"""``hdrd gap`` on many drives: each analysed on its own (in this process or on a cluster: the
job, :func:`gap_one`, runs on the workers as :mod:`hdrd.analysis.fleet_jobs`' jobs do),
one line each as they come in, in order; how often each effect was found; the reports in one
JSON file and the fitted models in a directory, written as the drives come in (the client
never holds the fleet's reports)."""

from __future__ import annotations

import json
import os
import sys
import tempfile
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from hdrd.analysis.evaluate import read_ref
from hdrd.analysis.fleet import Progress, Runner
from hdrd.analysis.fleet_jobs import DriveOutcome, why_skipped
from hdrd.analysis.gap.report import summary, to_report
from hdrd.analysis.gap.search import run_gap
from hdrd.analysis.progress import ProgressBar
from hdrd.io.files.access import UnsafeNameError, path_inside, shown_path
from hdrd.io.files.drivecolumns import DEFAULT_READ_LIMITS, ReadLimits
from hdrd.io.files.drivefiles import DriveRef
from hdrd.sim.gyro import save_model

if TYPE_CHECKING:
    from hdrd.analysis.progress import ProgressBar

__all__ = [
    "GapJob",
    "GapOutcome",
    "GapOutputs",
    "ReportStream",
    "gap_fleet",
    "gap_fleet_summary",
    "gap_one",
    "gap_refs",
    "gap_row",
    "gap_table_head",
]


@dataclass(frozen=True)
class GapJob:
    """The settings of ``hdrd gap``; result: also return the whole GapResult (to plot it)."""

    start: Any
    standstill: bool = False
    exclude: tuple[tuple[float, float], ...] = ()
    seed: int = 0
    result: bool = False
    read_limits: ReadLimits = DEFAULT_READ_LIMITS


@dataclass(frozen=True)
class GapOutcome:
    """What ``hdrd gap`` prints and writes of one drive: the summary, the report JSON, the
    fitted model (and the whole result when asked for)."""

    summary: str
    report: dict[str, Any]
    model: Any
    result: Any = None


def gap_one(ref: DriveRef, job: GapJob) -> DriveOutcome:
    """Read one drive and run the model-gap workflow on it; skipped (with the reason,
    :func:`why_skipped`) if it cannot be read or analysed."""
    try:
        log = read_ref(ref, job.read_limits)
        res = run_gap(log, job.start, standstill=job.standstill, exclude=job.exclude, seed=job.seed)
    except Exception as e:  # noqa: BLE001 - a drive's trouble is that drive's, said in one line
        return DriveOutcome(ref.name, skipped=why_skipped(ref.name, e))
    out = GapOutcome(summary(res), to_report(res), res.final_model, res if job.result else None)
    return DriveOutcome(ref.name, out)


def gap_refs(
    refs: Sequence[DriveRef], job: GapJob, runner: Runner, progress: Progress | None = None
) -> Iterator[DriveOutcome]:
    """Each drive's gap outcome, in the drives' order, as they come in."""
    yield from runner.map(gap_one, refs, job, progress=progress)


def gap_table_head(name_w: int) -> str:
    return (
        f"{'drive':<{name_w}} {'samples':>8} {'min':>6} {'gap':>8} {'-> gap':>8}  "
        "effects found (final model)"
    )


def gap_row(name: str, report: dict[str, Any], name_w: int) -> str:
    """One drive: samples, minutes, the gap before and after, the effects added (and the
    final model)."""
    log = report["log"]
    added = [s["effect"] for s in report["steps"]]
    return (
        f"{name:<{name_w}} {log['samples']:>8} {log['duration_s'] / 60:>6.1f} "
        f"{report['gap_initial']:>8.3g} {report['gap_final']:>8.3g}  "
        f"{', '.join(added) or '-'} ({' + '.join(report['final_model'])})"
    )


def gap_fleet_summary(found: Counter[str], n: int, skipped: int) -> str:
    """How many of the drives each effect was found in."""
    head = f"fleet: {n} drives analysed" + (f", {skipped} skipped" if skipped else "")
    if not found:
        return head + "; no effect missing from the model in any drive"
    # most often first, ties by name: the same line whatever order the drives came back in
    ranked = sorted(found.items(), key=lambda ek: (-ek[1], ek[0]))
    parts = [f"{e} in {k} ({100 * k / n:.0f} %)" for e, k in ranked]
    return head + "; effects found: " + ", ".join(parts)


def _indented(doc: Any, level: int) -> str:
    """``doc`` as ``json.dumps(..., indent=2)`` writes it ``level`` levels deep."""
    pad = "  " * level
    return "\n".join(pad + line for line in json.dumps(doc, indent=2).splitlines())


class ReportStream:
    """``{"drives": [report, ...], "skipped": [...]}`` written a report at a time, exactly as
    ``json.dumps(doc, indent=2)`` would write it whole; the file appears, whole, only on
    :meth:`finish` (a temporary file renamed), never half written."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent
        )
        self.tmp = Path(tmp)
        self.f = os.fdopen(fd, "w", encoding="utf-8")
        self.f.write('{\n  "drives": [')
        self.n = 0

    def add(self, report: dict[str, Any]) -> None:
        self.f.write(("," if self.n else "") + "\n" + _indented(report, 2))
        self.n += 1

    def finish(self, skipped: Sequence[str]) -> None:
        self.f.write(("\n  ]" if self.n else "]") + ',\n  "skipped": ')
        self.f.write(json.dumps(list(skipped), indent=2).replace("\n", "\n  ") + "\n}\n")
        self.f.flush()
        os.fsync(self.f.fileno())
        self.f.close()
        os.chmod(self.tmp, 0o644)
        os.replace(self.tmp, self.path)

    def __enter__(self) -> ReportStream:
        return self

    def __exit__(
        self, typ: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        if not self.f.closed:
            self.f.close()
        if self.tmp.exists():
            self.tmp.unlink()


@dataclass(frozen=True)
class GapOutputs:
    """What ``hdrd gap`` on many drives writes and how it goes on: ``out``, the folder of the
    fitted models (``OUT/NAME.yaml``); ``report``, the JSON file of the reports; ``strict``:
    stop at the first drive that cannot be used; ``progress``: a progress bar on stderr."""

    out: str | None = None
    report: str | None = None
    strict: bool = False
    progress: bool = True


def gap_fleet(outputs: GapOutputs, refs: Sequence[DriveRef], job: GapJob, runner: Runner) -> int:
    """Run ``hdrd gap`` on every drive; print and write as the drives come in. Exit status 0,
    or 1 if no drive could be analysed or a file could not be written. Raises DriveLogError
    (a drive cannot be read) and FleetError."""
    name_w = max(12, *(len(r.name) for r in refs))
    skipped: list[str] = []
    n_given = len(refs)
    paths: dict[str, Path] = {}
    if outputs.out:
        refs, paths, unnamed = model_paths(refs, outputs.out)
        skipped.extend(unnamed)
        if unnamed and outputs.strict:
            print(f"hdrd gap: {unnamed[0]}", file=sys.stderr)
            return 1
    bar = ProgressBar(f"gap {len(refs)} drives") if outputs.progress else None
    run = _FleetRun(outputs, name_w, paths, skipped, bar)
    print(gap_table_head(name_w), flush=True)
    try:
        with ReportStream(outputs.report) if outputs.report else _NoReport() as report:
            for o in gap_refs(refs, job, runner, bar):
                if not run.take(o, report):
                    return 1
            run.close_bar()
            for why in skipped:
                print(f"hdrd gap: skipped {why}", file=sys.stderr)
            if run.n_ok == 0:
                print(f"hdrd gap: none of the {n_given} drives can be analysed", file=sys.stderr)
                return 1
            report.finish(skipped)
    except OSError as e:
        where = f" ({e.filename})" if e.filename else ""
        print(f"hdrd gap: cannot write: {e.strerror or e}{where}", file=sys.stderr)
        return 1
    finally:
        run.close_bar()
    print(gap_fleet_summary(run.found, run.n_ok, len(skipped)))
    return 0


class _FleetRun:
    """What :func:`gap_fleet` keeps as the drives come in: the progress bar, the drives
    analysed and skipped, how often each effect was found."""

    def __init__(
        self,
        outputs: GapOutputs,
        name_w: int,
        paths: dict[str, Path],
        skipped: list[str],
        bar: ProgressBar | None,
    ) -> None:
        self.outputs, self.name_w, self.paths = outputs, name_w, paths
        self.skipped, self.bar = skipped, bar
        self.found: Counter[str] = Counter()
        self.n_ok = 0

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def take(self, o: DriveOutcome, report: ReportStream | _NoReport) -> bool:
        """Print and write one drive's outcome (its row, report and model); False when a
        drive skipped stops the run (--strict)."""
        if o.skipped is not None:
            if self.outputs.strict:
                self.close_bar()
                print(f"hdrd gap: {o.skipped}", file=sys.stderr)
                return False
            self.skipped.append(o.skipped)
            return True
        self.n_ok += 1
        rep = o.result.report
        self.found.update({s["effect"] for s in rep["steps"]})
        if self.bar is not None and self.bar.tty:
            sys.stderr.write("\r\033[K")  # the bar's line, cleared for the table's
        print(gap_row(o.name, rep, self.name_w), flush=True)
        report.add(rep)
        if self.outputs.out:
            # a link or a FIFO planted in OUT is refused, never followed
            save_model(o.result.model, self.paths[o.name], inside=self.outputs.out)
        return True


def model_paths(
    refs: Sequence[DriveRef], out: str
) -> tuple[list[DriveRef], dict[str, Path], list[str]]:
    """Where each drive's fitted model goes, ``OUT/NAME.yaml``: the drives whose name can be
    such a file (:func:`hdrd.io.files.access.path_inside`: never outside OUT), their paths, and why each
    other drive is left out (a name that would lead out of OUT; a file another drive already
    takes, or that would be a folder of another drive's file or hold it, ``a.yaml/b`` and
    ``a``; a folder already where the file goes, or a file where a folder must be)."""
    kept: list[DriveRef] = []
    paths: dict[str, Path] = {}
    taken: dict[Path, str] = {}
    folders: dict[Path, str] = {}  # folders the files taken need, and whose file needs each
    why: list[str] = []
    for r in refs:
        try:
            path = path_inside(out, r.name, ".yaml")
        except UnsafeNameError as e:
            why.append(f"{r.name}: {e}")
            continue
        clash = _clash(path, Path(out), taken, folders, r.name in paths)
        if clash:
            why.append(f"{r.name}: {clash}")
            continue
        taken[path] = r.name
        paths[r.name] = path
        for folder in path.relative_to(out).parents:
            folders.setdefault(Path(out) / folder, r.name)
        kept.append(r)
    return kept, paths, why


def _clash(
    path: Path, out: Path, taken: dict[Path, str], folders: dict[Path, str], named: bool
) -> str | None:
    """Why a drive's model cannot be ``path`` (None if it can), given the files and folders
    the drives before it take."""
    shown = shown_path(path)
    if path in taken or named:
        return f"its model would be {shown}, as that of an earlier drive"
    if path in folders:
        return f"its model would be {shown}, a folder of drive {folders[path]}'s model"
    for folder in path.relative_to(out).parents:
        above = out / folder
        if above in taken:
            return f"its model would be {shown}, inside drive {taken[above]}'s model file"
        if above.exists() and not above.is_dir():
            return f"its model would be {shown}, but {shown_path(above)} is a file"
    if path.is_dir():
        return f"its model would be {shown}, a folder that exists"
    return None


class _NoReport:
    def add(self, report: dict[str, Any]) -> None:
        pass

    def finish(self, skipped: Sequence[str]) -> None:
        pass

    def __enter__(self) -> _NoReport:
        return self

    def __exit__(self, *exc: object) -> None:
        pass
