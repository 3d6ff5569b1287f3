"""The per-drive work of ``hdrd evaluate``, ``hdrd tune`` and ``hdrd gap`` on a fleet, and the
client side that puts the results together, for either runner of :mod:`hdrd.analysis.fleet`.

The functions a worker runs take a drive's :class:`~hdrd.drivesources.DriveRef` (a path: the
worker reads the drive itself) and a small frozen job (the settings), and return small results:
a drive's Table II row without its traces, a gap report. They call exactly what the
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

import argparse
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.evaluate import (
    PAPER_PARAMS,
    PLUS_DEFAULTS,
    DriveResult,
    EvaluationError,
    PreparedDrive,
    evaluate_prepared,
    prepare_drive,
    read_ref,
)
from hdrd.analysis.fleet import Progress, Runner, batches, open_runner
from hdrd.analysis.prepare import DEFAULT_LIMITS, TRUTH_MAX_GAP_S
from hdrd.analysis.tune import (
    CHUNK_ELEMENTS,
    PARAM_NAMES,
    Candidates,
    TuneResult,
    check_budget,
    outcome,
    score_candidates,
    search,
)
from hdrd.calibrate import StandstillLimits
from hdrd.drivelog import DriveLogError
from hdrd.drivesources import DriveRef
from hdrd.hdr import HdrParams
from hdrd.hdrplus import GyroNoise, HdrPlusParams

__all__ = [
    "PLOT_PANELS_MAX",
    "DriveOutcome",
    "EvaluateJob",
    "GapJob",
    "GapOutcome",
    "PrepareJob",
    "evaluate_one",
    "evaluate_refs",
    "gap_one",
    "gap_refs",
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


# -- hdrd evaluate ------------------------------------------------------------------------------


@dataclass(frozen=True)
class EvaluateJob:
    """The settings ``hdrd evaluate`` scores every drive with (as
    :func:`hdrd.analysis.evaluate.evaluate_logs` takes them); traces: keep each drive's
    headings (for the per-drive plot)."""

    params: HdrParams = PAPER_PARAMS
    methods: tuple[str, ...] = ("none", "hdr")
    plus: HdrPlusParams = PLUS_DEFAULTS
    bias: float | None = None
    calibrate_seconds: float | None = None
    limits: StandstillLimits = DEFAULT_LIMITS
    truth_max_gap_s: float = TRUTH_MAX_GAP_S
    noise: GyroNoise | None = None
    traces: bool = False


def evaluate_one(ref: DriveRef, job: EvaluateJob) -> DriveOutcome:
    """Read one drive and score it as :func:`~hdrd.analysis.evaluate.evaluate_logs` does;
    skipped (with the reason) if it cannot be evaluated; EvaluationError if it cannot be read."""
    log = read_ref(ref)
    try:
        prep = prepare_drive(
            log, job.bias, job.calibrate_seconds, job.params.T, job.truth_max_gap_s, job.limits
        )
        r = evaluate_prepared(prep, job.params, job.methods, job.plus, job.noise)
    except EvaluationError as e:
        return DriveOutcome(ref.name, skipped=str(e))
    return DriveOutcome(ref.name, r if job.traces else slim(r))


def run_evaluate(
    args: argparse.Namespace, refs: Sequence[DriveRef], job: EvaluateJob
) -> tuple[list[DriveResult], list[str]]:
    """:func:`evaluate_refs` on the runner the command line asks for, with a progress bar on
    stderr for a fleet (more than :data:`PLOT_PANELS_MAX` drives) or a cluster, unless
    ``--no-progress``."""
    from hdrd.analysis.progress import ProgressBar

    with open_runner(args) as runner:
        show = not getattr(args, "no_progress", False) and (
            runner.distributed or len(refs) > PLOT_PANELS_MAX
        )
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
    raises EvaluationError)."""
    results: list[DriveResult] = []
    skipped: list[str] = []
    for o in runner.map(evaluate_one, refs, job, progress=progress):
        if o.skipped is None:
            results.append(o.result)
        elif len(refs) == 1:
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


def prepare_refs(refs: Sequence[DriveRef], job: PrepareJob) -> list[PreparedDrive]:
    """Read and prepare a batch of drives (kept on the worker for the search's rounds)."""
    return [prepare_drive(read_ref(r), job.bias, job.calibrate_seconds, job.T) for r in refs]


def steps_of(drives: Sequence[PreparedDrive]) -> list[int]:
    """Steps of each prepared drive (the search's units of work)."""
    return [int(d.steps.u.shape[0]) for d in drives]


def score_block(item: tuple[Sequence[PreparedDrive], Candidates], T: float) -> FloatArray:
    """Eψ / Td of every parameter set of a block on every drive of a batch: shape
    (drives, sets), each row a drive's share of the objective's sum."""
    drives, block = item
    e = score_candidates(drives, block, T)
    td = np.array([d.duration_min for d in drives])[:, None]
    return e / td


def evaluate_sets(
    drives: Sequence[PreparedDrive], sets: Sequence[HdrParams]
) -> list[list[DriveResult]]:
    """Per drive of a batch, its result with each parameter set (``none`` and ``hdr``)."""
    return [[slim(evaluate_prepared(d, p, ("none", "hdr"))) for p in sets] for d in drives]


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
) -> TuneResult:
    """:func:`hdrd.analysis.tune.tune` over drives a runner reads and prepares where it runs:
    the same search, the same objective bit for bit (the module docstring), the same result.
    EvaluationError for a drive that cannot be read or evaluated, ValueError for a bad
    budget."""
    if not train_refs:
        raise ValueError("tuning needs at least one training drive")
    check_budget(n_candidates, base)
    job = PrepareJob(bias, calibrate_seconds, base.T)
    train = runner.persist(prepare_refs, _batches(train_refs, runner.threads), job)
    test = runner.persist(prepare_refs, _batches(test_refs, runner.threads), job)
    steps = list(runner.map(steps_of, train, batch=1))  # and so: each drive could be prepared
    list(runner.map(steps_of, test, batch=1))
    n_drives = len(train_refs)
    longest = max(max(s) for s in steps)
    chunk = max(16, CHUNK_ELEMENTS // max(longest, 1))
    batch_steps = [sum(s) for s in steps]
    total = sum(batch_steps) * n_candidates
    done = 0

    def score(cand: Candidates) -> FloatArray:
        nonlocal done
        n_sets = cand[PARAM_NAMES[0]].shape[0]
        blocks = parameter_blocks(n_sets, chunk, len(train), runner.threads)
        shared = [runner.share({k: cand[k][a:b] for k in PARAM_NAMES}) for a, b in blocks]
        items = [(h, blk) for blk in shared for h in train]
        weights = [batch_steps[j] * (b - a) for a, b in blocks for j in range(len(train))]
        start = done

        def report(d: int, _: int) -> None:
            if progress is not None:
                progress(start + d, total)

        sums: list[FloatArray | None] = [None] * len(blocks)
        rows = runner.map(score_block, items, base.T, progress=report, weights=weights, batch=1)
        for i, part in enumerate(rows):
            q = i // len(train)
            for row in part:  # the drives in order, one after the other
                acc = sums[q]
                if acc is None:
                    sums[q] = row.copy()
                else:
                    acc += row
        done = start + sum(weights)
        out = np.empty(n_sets)
        for (a, b), acc in zip(blocks, sums):
            assert acc is not None
            out[a:b] = acc / n_drives
        return out

    def runs(
        sets: Sequence[HdrParams],
    ) -> tuple[list[list[DriveResult]], list[list[DriveResult]]]:
        tr = _per_set(runner.map(evaluate_sets, train, sets, batch=1), len(sets))
        te = _per_set(runner.map(evaluate_sets, test, sets, batch=1), len(sets))
        return tr, te

    cand, obj = search(score, n_candidates, seed, base)
    return outcome(base, cand, obj, seed, runs)


def _per_set(batches: Iterator[list[list[DriveResult]]], n_sets: int) -> list[list[DriveResult]]:
    out: list[list[DriveResult]] = [[] for _ in range(n_sets)]
    for batch in batches:
        for per_drive in batch:
            for i, r in enumerate(per_drive):
                out[i].append(r)
    return out


# -- hdrd gap -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class GapJob:
    """The settings of ``hdrd gap``; result: also return the whole GapResult (to plot it)."""

    start: Any
    standstill: bool = False
    exclude: tuple[tuple[float, float], ...] = ()
    seed: int = 0
    result: bool = False


@dataclass(frozen=True)
class GapOutcome:
    """What ``hdrd gap`` prints and writes of one drive: the summary, the report JSON, the
    fitted model (and the whole result when asked for)."""

    summary: str
    report: dict[str, Any]
    model: Any
    result: Any = None


def gap_one(ref: DriveRef, job: GapJob) -> DriveOutcome:
    """Read one drive and run the model-gap workflow on it; skipped (with the reason) if it
    cannot be analysed; DriveLogError if it cannot be read."""
    from hdrd.analysis.gap.data import GapError
    from hdrd.analysis.gap.report import summary, to_report
    from hdrd.analysis.gap.search import run_gap

    try:
        log = ref.read()
    except (OSError, UnicodeDecodeError) as e:
        raise DriveLogError(
            f"cannot read {ref.path}: {getattr(e, 'strerror', None) or e}"
        ) from None
    try:
        res = run_gap(log, job.start, standstill=job.standstill, exclude=job.exclude, seed=job.seed)
    except (GapError, ValueError) as e:
        return DriveOutcome(ref.name, skipped=str(e))
    out = GapOutcome(summary(res), to_report(res), res.final_model, res if job.result else None)
    return DriveOutcome(ref.name, out)


def gap_refs(
    refs: Sequence[DriveRef], job: GapJob, runner: Runner, progress: Progress | None = None
) -> Iterator[DriveOutcome]:
    """Each drive's gap outcome, in the drives' order, as they come in."""
    yield from runner.map(gap_one, refs, job, progress=progress)
