"""The per-drive work of ``hdrd evaluate`` and ``hdrd tune`` on a fleet, and the client side that
puts the results together, for either runner of :mod:`hdrd.analysis.fleet` (``hdrd gap``'s job
is :mod:`hdrd.analysis.gap.fleet`'s: gap sits above these shared modules).

The functions a worker runs take a drive's :class:`~hdrd.io.files.drivefiles.DriveRef` (a path: the
worker reads the drive itself) and a small frozen job (the settings), and return small results:
a drive's Table II row without its traces. They call exactly what the
single-process commands call, with the same arguments, so the numbers are the same bit for bit
(tests/test_fleet.py).

Tuning on a cluster: the training drives are prepared once, where they stay (a worker's
memory); each round of the search sends the round's parameter sets to every worker once, and
each task returns, per drive of its batch, Eψ / Td of every set of a block. The client sums
those per-drive rows in the drives' order, one after the other, as numpy's mean over the
drives does in :func:`hdrd.analysis.tune.objective`: the objective, and so the search and its
best set, are the single-process ones bit for bit. The parameter blocks are the
single-process chunks (:data:`hdrd.analysis.tune.CHUNK_ELEMENTS`), split further (never below
two sets, where numpy's mean of one set sums differently) when there are fewer batches of
drives than workers to keep busy.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.evaluate import (
    DEFAULTS,
    DriveResult,
    EvaluationError,
    PreparedDrive,
    evaluate_prepared,
    prepare_drive,
    read_ref,
    trace_columns,
)
from hdrd.analysis.fleet import Progress, Runner, Where, batches, open_runner
from hdrd.analysis.outages import OutageSpec, run_outages
from hdrd.analysis.prepare import DEFAULT_LIMITS, PAPER_PARAMS, TRUTH_MAX_GAP_S
from hdrd.analysis.progress import ProgressBar
from hdrd.analysis.tune import (
    CHUNK_ELEMENTS,
    PARAM_NAMES,
    Candidates,
    Interrupted,
    TuneResult,
    check_budget,
    check_held_out,
    content_key,
    score_candidates,
    search_outcome,
)
from hdrd.core.calibrate import CalibrationLimits
from hdrd.core.hdr import HdrParams
from hdrd.core.methods import MethodSetup
from hdrd.errors import HdrdError, clipped
from hdrd.io.files.access import printable
from hdrd.io.files.drivecolumns import DEFAULT_READ_LIMITS, ReadLimits
from hdrd.io.files.drivefiles import DriveRef
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "PLOT_PANELS_MAX",
    "DriveOutcome",
    "EvaluateJob",
    "PrepareJob",
    "evaluate_one",
    "estimated_work_s",
    "evaluate_refs",
    "parameter_blocks",
    "run_evaluate",
    "slim",
    "tune_fleet",
]

FloatArray = npt.NDArray[np.float64]

PLOT_PANELS_MAX = 12
"""Up to this many drives, ``--plot`` draws each drive's heading (the traces come back with
the results); beyond, a fleet: the distribution of NEψ per method."""
MIN_SUB_BLOCK = 16
"""Fewest parameter sets in a block split off a chunk for parallelism."""

_EMPTY = np.empty(0)


def slim(r: DriveResult) -> DriveResult:
    """A drive's result without its traces (headings and truth per step): what a fleet's
    table, summary, JSON and distribution plot need, a few hundred bytes."""
    return replace(r, t_end=_EMPTY, truth=_EMPTY, heading={})


@dataclass(frozen=True)
class DriveOutcome:
    """One drive's outcome: its result, or why it was skipped (one line)."""

    name: str
    result: Any = None
    skipped: str | None = None


def why_skipped(name: str, e: Exception) -> str:
    """The one line that says why drive ``name`` could not be used: the message of hdrd's own
    error (it names the file and row, or the drive); for anything else, the drive and what
    went wrong, so that one bad drive never stops a fleet with a traceback."""
    if isinstance(e, HdrdError):
        msg = str(e)
        return msg if name in msg else f"{name}: {msg}"
    if isinstance(e, (MemoryError, RecursionError)):
        return f"{name}: too large to analyse in the memory available ({type(e).__name__})"
    what = clipped(printable(" ".join(str(e).split())), 160)
    return (
        f"{name}: cannot be analysed: internal error {type(e).__name__}: {what} (please report it)"
    )


def read_prepared(ref: DriveRef, job: PrepareJob) -> PreparedDrive | str:
    """One drive read and prepared as :func:`prepare_refs` prepares it, or why it cannot be
    (:func:`why_skipped`)."""
    try:
        return prepare_drive(read_ref(ref, job.read_limits), job.bias, job.calibrate_seconds, job.T)
    except Exception as e:  # noqa: BLE001 - a drive's trouble is that drive's, said in one line
        return why_skipped(ref.name, e)


# -- hdrd evaluate ------------------------------------------------------------------------------


@dataclass(frozen=True)
class EvaluateJob:
    """The settings ``hdrd evaluate`` scores every drive with (as
    :func:`hdrd.analysis.evaluate.evaluate_logs` takes them); traces: keep each drive's
    headings (for the per-drive plot)."""

    methods: tuple[str, ...] = ("none", "hdr")
    setup: MethodSetup = DEFAULTS
    bias: float | None = None
    calibrate_seconds: float | None = None
    limits: CalibrationLimits = DEFAULT_LIMITS
    truth_max_gap_s: float = TRUTH_MAX_GAP_S
    traces: bool = False
    strict: bool = False
    read_limits: ReadLimits = DEFAULT_READ_LIMITS
    outages: OutageSpec | None = None
    """``--outages``: each drive's GNSS outages through the aiding path too."""
    trace: bool = False
    """``--trace``: each drive's headings per step (:func:`hdrd.analysis.evaluate.
    trace_columns`)."""


def with_outages(
    r: DriveResult, prep: PreparedDrive, log: DriveLog, job: EvaluateJob
) -> DriveResult:
    """The result with its GNSS outages (:func:`hdrd.analysis.outages.run_outages`); a drive
    too short for one, or without a course to aid from, says so among its warnings."""
    assert job.outages is not None
    try:
        o = run_outages(prep, log, job.outages, job.methods, job.setup)
    except EvaluationError as e:
        why = str(e).removeprefix(f"{r.name}: ")
        return replace(r, warnings=(*r.warnings, f"{r.name}: no outages scored: {why}"))
    return replace(r, outages=o)


def evaluate_one(ref: DriveRef, job: EvaluateJob) -> DriveOutcome:
    """Read one drive and score it as :func:`~hdrd.analysis.evaluate.evaluate_logs` does;
    skipped (with the reason, :func:`why_skipped`) if it cannot be read or evaluated."""
    try:
        log = read_ref(ref, job.read_limits)
        prep = prepare_drive(
            log, job.bias, job.calibrate_seconds, job.setup.hdr.T, job.truth_max_gap_s, job.limits
        )
        r = evaluate_prepared(prep, job.methods, job.setup)
        if job.outages is not None:
            r = with_outages(r, prep, log, job)
        if job.trace:
            r = replace(r, trace=trace_columns(prep, job.setup))
    except Exception as e:  # noqa: BLE001 - a drive's trouble is that drive's, said in one line
        return DriveOutcome(ref.name, skipped=why_skipped(ref.name, e))
    if job.strict and r.warnings:  # --strict: data that looks wrong is refused, not scored
        return DriveOutcome(ref.name, skipped=r.warnings[0])
    return DriveOutcome(ref.name, r if job.traces else slim(r))


WORK_S_PER_BYTE = 60e-9
"""One process's time to read and evaluate a drive, per byte of its file (CSV and Parquet
alike, about 60 ns on the machine of bench/RESULTS.md): what :func:`estimated_work_s`
counts."""


def _size(ref: DriveRef, sharing: int) -> int:
    """Bytes of a drive's file (its share of a file holding ``sharing`` drives), or of a
    partition's files; 0 if they cannot be seen."""
    try:
        if os.path.isdir(ref.path):
            return sum(e.stat().st_size for e in os.scandir(ref.path) if e.is_file())
        return os.path.getsize(ref.path) // max(1, sharing)
    except OSError:
        return 0


def estimated_work_s(refs: Sequence[DriveRef]) -> float:
    """Seconds ``hdrd evaluate`` would take on the drives in one process, estimated from their
    files' sizes (:data:`WORK_S_PER_BYTE`; no file is read)."""
    sharing = Counter(r.path for r in refs)
    return WORK_S_PER_BYTE * sum(_size(r, sharing[r.path]) for r in refs)


def run_evaluate(
    where: Where,
    refs: Sequence[DriveRef],
    job: EvaluateJob,
    progress: bool = True,
    say: Callable[[str], None] | None = None,
) -> tuple[list[DriveResult], list[str]]:
    """:func:`evaluate_refs` on the runner ``where`` asks for (in this process when a local
    cluster would not pay for itself: :func:`hdrd.analysis.fleet.open_runner`, ``say`` told),
    with a progress bar on stderr (``progress``) for a fleet (more than
    :data:`PLOT_PANELS_MAX` drives) or a cluster."""
    with open_runner(where, estimated_work_s(refs), say) as runner:
        show = progress and (runner.distributed or len(refs) > PLOT_PANELS_MAX)
        bar = ProgressBar(f"evaluate {len(refs)} drives") if show else None
        try:
            return evaluate_refs(refs, job, runner, bar)
        finally:
            if bar is not None:
                bar.close()


def evaluate_refs(
    refs: Sequence[DriveRef], job: EvaluateJob, runner: Runner, progress: Progress | None = None
) -> tuple[list[DriveResult], list[str]]:
    """Every drive's result in the drives' order, and why each skipped one was skipped (as
    :func:`~hdrd.analysis.evaluate.evaluate_logs`: a single drive that cannot be evaluated
    raises EvaluationError; so does the first one with ``job.strict``)."""
    results: list[DriveResult] = []
    skipped: list[str] = []
    for o in runner.map(evaluate_one, refs, job, progress=progress):
        if o.skipped is None:
            results.append(o.result)
        elif len(refs) == 1 or job.strict:
            raise EvaluationError(o.skipped)
        else:
            skipped.append(o.skipped)
    return results, skipped


# -- hdrd tune ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class PrepareJob:
    """How :func:`hdrd.analysis.tune.tune` prepares its drives."""

    bias: float | None = None
    calibrate_seconds: float | None = None
    T: float = PAPER_PARAMS.T
    read_limits: ReadLimits = DEFAULT_READ_LIMITS


def prepare_refs(refs: Sequence[DriveRef], job: PrepareJob) -> list[PreparedDrive | str]:
    """Read and prepare a batch of drives (kept on the worker for the search's rounds); a
    drive that cannot be is why (:func:`read_prepared`), and takes no part in the search."""
    return [read_prepared(r, job) for r in refs]


def _good(drives: Sequence[PreparedDrive | str]) -> list[PreparedDrive]:
    return [d for d in drives if not isinstance(d, str)]


def steps_of(drives: Sequence[PreparedDrive | str]) -> list[int | str]:
    """Steps of each prepared drive (the search's units of work), or why it was left out."""
    return [d if isinstance(d, str) else int(d.steps.u.shape[0]) for d in drives]


def keys_of(drives: Sequence[PreparedDrive | str]) -> list[tuple[str, str]]:
    """(name, :func:`~hdrd.analysis.tune.content_key`) of each prepared drive of a batch."""
    return [(d.name, content_key(d)) for d in _good(drives)]


def score_block(item: tuple[Sequence[PreparedDrive | str], Candidates], T: float) -> FloatArray:
    """Eψ / Td of every parameter set of a block on every prepared drive of a batch: shape
    (drives, sets), each row a drive's share of the objective's sum."""
    drives, block = item
    good = _good(drives)
    e = score_candidates(good, block, T)
    td = np.array([d.duration_min for d in good])[:, None]
    return e / td


def evaluate_sets(
    drives: Sequence[PreparedDrive | str], sets: Sequence[HdrParams]
) -> list[list[DriveResult]]:
    """Per prepared drive of a batch, its result with each parameter set (``none``, ``hdr``)."""
    return [
        [
            slim(evaluate_prepared(d, methods=("none", "hdr"), setup=MethodSetup(hdr=p)))
            for p in sets
        ]
        for d in _good(drives)
    ]


def parameter_blocks(
    n_sets: int, chunk: int, n_batches: int, threads: int
) -> list[tuple[int, int]]:
    """[a, b) ranges of the parameter sets scored together: the single-process chunks, each
    split into blocks of at least MIN_SUB_BLOCK sets when batches alone leave workers idle."""
    out: list[tuple[int, int]] = []
    for a in range(0, n_sets, chunk):
        b = min(n_sets, a + chunk)
        parts = 1
        if n_batches < 2 * threads:
            parts = max(1, min(math.ceil(2 * threads / n_batches), (b - a) // MIN_SUB_BLOCK))
        edges = [a + (b - a) * i // parts for i in range(parts + 1)]
        out.extend(zip(edges[:-1], edges[1:]))
    return out


def _batches(refs: Sequence[DriveRef], threads: int) -> list[list[DriveRef]]:
    return [[refs[i] for i in idx] for idx in batches(len(refs), threads)]


def _usable_steps(
    all_steps: list[list[int | str]],
    test_steps: list[list[int | str]],
    n_train: int,
    strict: bool,
    skipped: list[str] | None,
) -> tuple[list[list[int]], int]:
    """The training drives' step counts per batch, without the drives that cannot be used
    (why is added to ``skipped``; EvaluationError with ``strict`` or when none is left), and
    how many drives are left."""
    why = [x for s in all_steps + test_steps for x in s if isinstance(x, str)]
    if why and strict:
        raise EvaluationError(why[0])
    steps = [[x for x in s if not isinstance(x, str)] for s in all_steps]
    n_drives = sum(len(s) for s in steps)
    if n_drives == 0 and n_train == 1:
        raise EvaluationError(why.pop(0))
    if skipped is not None:
        skipped.extend(why)
    if n_drives == 0:
        raise EvaluationError(f"none of the {n_train} training drives can be used")
    return steps, n_drives


@dataclass
class _FleetScore:
    """The tuning objective over the training drives where they are held: each candidate
    set's error summed over the drives, over ``n_drives``; progress counts steps times sets
    over all the calls (``total``)."""

    runner: Runner
    train: list[Any]
    T: float
    chunk: int
    batch_steps: list[int]
    n_drives: int
    total: int
    progress: Progress | None
    done: int = 0

    def __call__(self, cand: Candidates) -> FloatArray:
        runner, train, batch_steps = self.runner, self.train, self.batch_steps
        n_sets = cand[PARAM_NAMES[0]].shape[0]
        blocks = parameter_blocks(n_sets, self.chunk, len(train), runner.threads)
        shared = [runner.share({k: cand[k][a:b] for k in PARAM_NAMES}) for a, b in blocks]
        items = [(h, blk) for blk in shared for h in train]
        weights = [batch_steps[j] * (b - a) for a, b in blocks for j in range(len(train))]
        start = self.done

        def report(d: int, _: int) -> None:
            if self.progress is not None:
                self.progress(start + d, self.total)

        sums: list[FloatArray | None] = [None] * len(blocks)
        rows = runner.map(score_block, items, self.T, progress=report, weights=weights, batch=1)
        got = 0
        try:
            for i, part in enumerate(rows):
                q = i // len(train)
                for row in part:  # the drives in order, one after the other
                    acc = sums[q]
                    if acc is None:
                        sums[q] = row.copy()
                    else:
                        acc += row
                got = i + 1
        except KeyboardInterrupt:
            full = got // len(train)  # the blocks summed over every drive
            raise Interrupted(self._objective(blocks[:full], sums)) from None
        self.done = start + sum(weights)
        return self._objective(blocks, sums)

    def _objective(
        self, blocks: list[tuple[int, int]], sums: list[FloatArray | None]
    ) -> FloatArray:
        """Each set's objective, for the sets of ``blocks`` (the first blocks)."""
        out = np.empty(blocks[-1][1] if blocks else 0)
        for (a, b), acc in zip(blocks, sums):
            assert acc is not None
            out[a:b] = acc / self.n_drives
        return out


def tune_fleet(
    runner: Runner,
    train_refs: Sequence[DriveRef],
    test_refs: Sequence[DriveRef] = (),
    n_candidates: int = 2000,
    seed: int = 0,
    *,
    base: HdrParams = PAPER_PARAMS,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    progress: Progress | None = None,
    strict: bool = False,
    skipped: list[str] | None = None,
    read_limits: ReadLimits = DEFAULT_READ_LIMITS,
) -> TuneResult:
    """:func:`hdrd.analysis.tune.tune` over drives a runner reads and prepares where it runs:
    the same search, the same objective bit for bit (the module docstring), the same result.
    A drive that cannot be read or evaluated takes no part, and why is added to ``skipped``
    (with ``strict``, or when no training drive is left: EvaluationError); ValueError for a
    bad budget."""
    if not train_refs:
        raise ValueError("tuning needs at least one training drive")
    check_budget(n_candidates, base)
    job = PrepareJob(bias, calibrate_seconds, base.T, read_limits)
    train = runner.persist(prepare_refs, _batches(train_refs, runner.threads), job)
    test = runner.persist(prepare_refs, _batches(test_refs, runner.threads), job)
    all_steps = list(runner.map(steps_of, train, batch=1))
    test_steps = list(runner.map(steps_of, test, batch=1))
    steps, n_drives = _usable_steps(all_steps, test_steps, len(train_refs), strict, skipped)
    if test_refs:
        keys = [list(runner.map(keys_of, part, batch=1)) for part in (train, test)]
        check_held_out(*([k for batch in part for k in batch] for part in keys))
    longest = max(max(s, default=0) for s in steps)
    batch_steps = [sum(s) for s in steps]
    score = _FleetScore(
        runner,
        train,
        base.T,
        chunk=max(16, CHUNK_ELEMENTS // max(longest, 1)),
        batch_steps=batch_steps,
        n_drives=n_drives,
        total=sum(batch_steps) * n_candidates,
        progress=progress,
    )

    def runs(
        sets: Sequence[HdrParams],
    ) -> tuple[list[list[DriveResult]], list[list[DriveResult]]]:
        tr = _per_set(runner.map(evaluate_sets, train, sets, batch=1), len(sets))
        te = _per_set(runner.map(evaluate_sets, test, sets, batch=1), len(sets))
        return tr, te

    return search_outcome(score, n_candidates, seed, base, runs)


def _per_set(batches: Iterator[list[list[DriveResult]]], n_sets: int) -> list[list[DriveResult]]:
    out: list[list[DriveResult]] = [[] for _ in range(n_sets)]
    for batch in batches:
        for per_drive in batch:
            for i, r in enumerate(per_drive):
                out[i].append(r)
    return out
