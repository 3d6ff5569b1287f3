"""Tuning HDR's parameters on training drives, checked on test drives (paper Sec. 5.2.3).

The paper hand-tuned one parameter set (Table III) "to minimize the bottom line in Table II,
and specifically the Average of all Normalized Average Heading Errors", then applied it
unchanged to five further drives: 9.2x better than no HDR on the nine training drives,
6.9x on the test drives. :func:`tune` does the same search automatically:

1. random search: ``n_candidates * (1 - refine_fraction)`` parameter sets (i_c, τ, Θw, c1,
   c2), each drawn log-uniformly from :data:`RANGES` (factors of 4-10 around Table III),
   rounded to three significant digits (the paper's precision), plus the starting set itself;
2. local refinement: the rest of the budget, in ``refine_rounds`` rounds, perturbs the best
   ``top_k`` sets so far by log-normal factors (spread 1.5, then smaller each round);
3. objective: the mean NEψ (Eq. 13, deg/min) over the training drives, smaller is better.

The drives are prepared once, as ``hdrd evaluate`` prepares them (:mod:`hdrd.analysis.prepare`:
the daemon's block code and stepper, the bias measured per drive), and every candidate is
scored on those steps with :func:`hdrd.core.hdr.run_many`, which steps thousands of parameter sets
together as numpy arrays, yaw for yaw what the daemon's HDR step gives (tests/test_tune.py);
the winner and the starting set are then re-run through :func:`hdrd.analysis.evaluate.
evaluate_prepared` for the reported numbers, so they are exactly what ``hdrd evaluate``
prints. Reproducible by seed.

Pure except for the optional progress callback; :mod:`hdrd.commands.tune` is the ``hdrd tune``
edge.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.evaluate import (
    DriveResult,
    EvaluationError,
    PreparedDrive,
    Summary,
    evaluate_prepared,
    prepare_drive,
    summarize,
)
from hdrd.analysis.metrics import e_psi
from hdrd.analysis.prepare import PAPER_PARAMS
from hdrd.core.hdr import HdrParams, run_many
from hdrd.core.methods import MethodSetup
from hdrd.io.files.drivelog import DriveLog

__all__ = [
    "CHUNK_ELEMENTS",
    "Interrupted",
    "PARAM_NAMES",
    "RANGES",
    "Progress",
    "Runs",
    "Score",
    "TuneResult",
    "check_budget",
    "check_held_out",
    "content_key",
    "format_report",
    "interrupted_json",
    "objective",
    "outcome",
    "params_yaml",
    "refine_candidates",
    "sample_candidates",
    "score_candidates",
    "search",
    "search_outcome",
    "to_json",
    "tune",
]

FloatArray = npt.NDArray[np.float64]
Candidates = dict[str, FloatArray]
Progress = Callable[[int, int], None]
"""progress(done, total): work units (steps x parameter sets) done so far, of total."""

PARAM_NAMES = ("i_c", "tau", "theta_w", "c1", "c2")
RANGES: dict[str, tuple[float, float]] = {
    "i_c": (0.0042, 0.21),  # deg/s per step; Table III 0.0422, /10 .. x5
    "tau": (0.075, 7.5),  # s; Table III 0.75, /10 .. x10
    "theta_w": (0.11, 2.8),  # deg/s; Table III 0.564, /5 .. x5
    "c1": (0.016, 1.6),  # -; Table III 0.16, /10 .. x10
    "c2": (0.45, 5.4),  # -; Table III 1.80, /4 .. x3
}
"""Log-uniform search ranges of the random phase (refinement may step outside them)."""

CHUNK_ELEMENTS = 1 << 22
"""Largest (steps x parameter sets) block scored at once: bounds memory to ~32 MB per array."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a tuning, with what was done. From a score: ``scored``, its values for
    the first sets it was given (Eψ per drive and set from :func:`score_candidates`, the
    objective from a :data:`Score`). From :func:`search` and :func:`tune`: ``cand``, every set
    scored so far in the order scored, and ``scored``, their objective."""

    def __init__(self, scored: FloatArray, cand: Candidates | None = None) -> None:
        super().__init__()
        self.scored = scored
        self.cand = cand

    def best(self, base: HdrParams) -> tuple[HdrParams, float] | None:
        """The best set so far and its objective (None if no set was scored)."""
        if self.cand is None or self.scored.shape[0] == 0:
            return None
        i = int(np.argsort(self.scored, kind="stable")[0])
        return _params(base, self.cand, i), float(self.scored[i])


def _sig3(a: FloatArray) -> FloatArray:
    """Round to three significant digits (clean decimals in the YAML snippet)."""
    return np.array([float(f"{v:.3g}") for v in a.tolist()], dtype=np.float64)


def sample_candidates(
    rng: np.random.Generator, n: int, ranges: dict[str, tuple[float, float]] = RANGES
) -> Candidates:
    """n parameter sets drawn log-uniformly from ``ranges``, three significant digits."""
    out: Candidates = {}
    for name in PARAM_NAMES:
        lo, hi = ranges[name]
        out[name] = _sig3(np.exp(rng.uniform(math.log(lo), math.log(hi), n)))
    return out


def refine_candidates(
    rng: np.random.Generator, centres: Candidates, n: int, spread: float
) -> Candidates:
    """n parameter sets around the given centres (taken in turn): each parameter multiplied
    by exp(N(0, ln spread)), three significant digits."""
    m = centres[PARAM_NAMES[0]].shape[0]
    pick = np.arange(n) % m
    sigma = math.log(spread)
    return {
        name: _sig3(centres[name][pick] * np.exp(rng.normal(0.0, sigma, n))) for name in PARAM_NAMES
    }


def _concat(a: Candidates, b: Candidates) -> Candidates:
    return {k: np.concatenate([a[k], b[k]]) for k in PARAM_NAMES}


def _take(c: Candidates, idx: npt.NDArray[np.int64]) -> Candidates:
    return {k: c[k][idx] for k in PARAM_NAMES}


def score_candidates(
    drives: Sequence[PreparedDrive],
    cand: Candidates,
    T: float = 1.0,
    progress: Progress | None = None,
    done0: int = 0,
    total: int | None = None,
) -> FloatArray:
    """Eψ (deg, Eq. 12) of every parameter set on every drive: shape (drives, sets).

    Runs :func:`hdrd.core.hdr.run_many` (all three enhancements on) over blocks of parameter sets
    small enough to bound memory.
    """
    P = cand[PARAM_NAMES[0]].shape[0]
    out = np.empty((len(drives), P))
    if P == 0 or not drives:
        return out
    longest = max(d.steps.u.shape[0] for d in drives)
    chunk = max(16, CHUNK_ELEMENTS // max(longest, 1))
    steps_all = sum(d.steps.u.shape[0] for d in drives)
    total = total if total is not None else steps_all * P
    done = done0
    a = 0
    try:
        for a in range(0, P, chunk):
            b = min(P, a + chunk)
            ic, ta, th, k1, k2 = (cand[k][a:b] for k in PARAM_NAMES)
            for j, d in enumerate(drives):
                yaw = run_many(d.steps.u, ic, ta, th, k1, k2, T=T)
                out[j, a:b] = e_psi(yaw, d.truth, d.k, d.align_n)
                done += d.steps.u.shape[0] * (b - a)
                if progress is not None:
                    progress(done, total)
    except KeyboardInterrupt:
        raise Interrupted(out[:, :a]) from None  # the chunks finished on every drive
    return out


def objective(e: FloatArray, drives: Sequence[PreparedDrive]) -> FloatArray:
    """Mean NEψ over drives (deg/min) for each parameter set, from Eψ of shape (drives, sets).
    The sum over drives runs in the drives' order, one drive after the other (numpy's
    reduction along the first axis), which a fleet's sum reproduces bit for bit."""
    td = np.array([d.duration_min for d in drives])[:, None]
    return np.mean(e / td, axis=0)


def _params(base: HdrParams, c: Candidates, i: int) -> HdrParams:
    v = {k: float(c[k][i]) for k in PARAM_NAMES}
    return replace(base, i_c=v["i_c"], tau=v["tau"], theta_w=v["theta_w"], c1=v["c1"], c2=v["c2"])


@dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`tune`.

    baseline: the starting parameters (default: the paper's Table III). best: the tuned set.
    train, test: per label ("baseline", "tuned") the evaluated drives (scalar run_batch).
    objective_baseline, objective_best: mean training NEψ (deg/min) as scored by run_many.
    n_evaluated: parameter sets scored (the starting set included). top: the best few sets
    with their objective, best first.
    """

    baseline: HdrParams
    best: HdrParams
    train: dict[str, list[DriveResult]]
    test: dict[str, list[DriveResult]]
    objective_baseline: float
    objective_best: float
    n_evaluated: int
    seed: int
    top: list[tuple[HdrParams, float]]

    def summary(self, which: str, label: str) -> Summary | None:
        results = (self.train if which == "train" else self.test)[label]
        return summarize(results) if results else None


def _prepare(
    logs: Sequence[DriveLog | PreparedDrive],
    bias: float | None,
    calibrate_seconds: float | None,
    T: float,
) -> list[PreparedDrive]:
    return [
        d if isinstance(d, PreparedDrive) else prepare_drive(d, bias, calibrate_seconds, T)
        for d in logs
    ]


Score = Callable[[Candidates], FloatArray]
"""score(sets) -> the objective of each set (mean training NEψ, deg/min): in this process
(:func:`tune`) or summed over a fleet's drives on a cluster (:mod:`hdrd.analysis.fleet_jobs`)."""


def check_budget(n_candidates: int, base: HdrParams) -> None:
    """ValueError for a budget or a starting set that :func:`search` cannot take."""
    if n_candidates < 1:
        raise ValueError(f"n_candidates must be >= 1, got {n_candidates}")
    if not (base.lowpass and base.turn_switch and base.attenuator and base.enabled):
        raise ValueError("tuning searches the full HDR (all three enhancements on)")


def search(
    score: Score,
    n_candidates: int,
    seed: int,
    base: HdrParams = PAPER_PARAMS,
    ranges: dict[str, tuple[float, float]] = RANGES,
    refine_fraction: float = 0.3,
    refine_rounds: int = 2,
    top_k: int = 10,
) -> tuple[Candidates, FloatArray]:
    """The search of the module docstring (random phase, then refinement rounds around the
    best so far): every set scored, and its objective. ``score`` is called once per round, in
    order; the first set is ``base``'s."""
    rng = np.random.default_rng(seed)
    n_refine = round((n_candidates - 1) * refine_fraction) if n_candidates > 1 else 0
    n_random = n_candidates - 1 - n_refine
    rounds = max(1, refine_rounds) if n_refine else 0
    per_round = [n_refine // rounds + (1 if r < n_refine % rounds else 0) for r in range(rounds)]

    start = {k: np.array([getattr(base, k)], dtype=np.float64) for k in PARAM_NAMES}
    cand = _concat(start, sample_candidates(rng, n_random, ranges))
    obj = _scored(score, cand, {k: np.empty(0) for k in PARAM_NAMES}, np.empty(0))
    spread = 1.5
    for n_r in per_round:
        if n_r == 0:
            continue
        order = np.argsort(obj, kind="stable")[: max(1, top_k)]
        new = refine_candidates(rng, _take(cand, order), n_r, spread)
        obj = np.concatenate([obj, _scored(score, new, cand, obj)])
        cand = _concat(cand, new)
        spread = 1.0 + (spread - 1.0) / 2.5
    return cand, obj


def _scored(score: Score, new: Candidates, cand: Candidates, obj: FloatArray) -> FloatArray:
    """score(new); on Ctrl-C, :class:`Interrupted` with every set scored so far (``cand``,
    then the first of ``new`` that the score finished) and their objective."""
    try:
        return score(new)
    except KeyboardInterrupt as e:
        part = e.scored if isinstance(e, Interrupted) else np.empty(0)
        k = part.shape[0]
        done = _take(new, np.arange(k, dtype=np.int64))
        raise Interrupted(np.concatenate([obj, part]), _concat(cand, done)) from None


def search_outcome(
    score: Score, n_candidates: int, seed: int, base: HdrParams, runs: Runs, **kw: Any
) -> TuneResult:
    """:func:`search`, then its :func:`outcome`; Ctrl-C in either is :class:`Interrupted`
    with the sets scored so far."""
    cand, obj = search(score, n_candidates, seed, base, **kw)
    try:
        return outcome(base, cand, obj, seed, runs)
    except KeyboardInterrupt:
        raise Interrupted(obj, cand) from None


Runs = Callable[[Sequence[HdrParams]], tuple[list[list[DriveResult]], list[list[DriveResult]]]]
"""runs(param sets) -> (training, test): per set, the drives evaluated with it."""


def outcome(
    base: HdrParams, cand: Candidates, obj: FloatArray, seed: int, runs: Runs
) -> TuneResult:
    """The :class:`TuneResult` of a finished :func:`search`: the best set, the top ten, and
    the drives evaluated (``runs``) with the starting set and the best."""
    order = np.argsort(obj, kind="stable")
    best_i = int(order[0])
    best = _params(base, cand, best_i)
    top = [(_params(base, cand, int(i)), float(obj[i])) for i in order[:10]]
    train, test = runs([base, best])
    return TuneResult(
        baseline=base,
        best=best,
        train={"baseline": train[0], "tuned": train[1]},
        test={"baseline": test[0], "tuned": test[1]},
        objective_baseline=float(obj[0]),
        objective_best=float(obj[best_i]),
        n_evaluated=int(cand["i_c"].shape[0]),
        seed=seed,
        top=top,
    )


def tune(
    train_logs: Sequence[DriveLog | PreparedDrive],
    test_logs: Sequence[DriveLog | PreparedDrive] = (),
    n_candidates: int = 2000,
    seed: int = 0,
    *,
    base: HdrParams = PAPER_PARAMS,
    bias: float | None = None,
    calibrate_seconds: float | None = None,
    ranges: dict[str, tuple[float, float]] = RANGES,
    refine_fraction: float = 0.3,
    refine_rounds: int = 2,
    top_k: int = 10,
    progress: Progress | None = None,
) -> TuneResult:
    """Search i_c, τ, Θw, c1, c2 minimising the mean NEψ over the training drives.

    n_candidates: parameter sets scored in all (the starting set ``base`` is one of them, so
    the result is never worse than it on the training drives). bias/calibrate_seconds: the
    static bias, as in :func:`hdrd.analysis.evaluate.prepare_drive` (None, None: measured per
    drive, as ``hdrd evaluate`` does). Raises EvaluationError
    for a drive that cannot be evaluated, ValueError for a bad budget.
    """
    if not train_logs:
        raise ValueError("tuning needs at least one training drive")
    check_budget(n_candidates, base)
    train = _prepare(train_logs, bias, calibrate_seconds, base.T)
    test = _prepare(test_logs, bias, calibrate_seconds, base.T)
    steps_all = sum(d.steps.u.shape[0] for d in train)
    total = steps_all * n_candidates
    done = 0

    def score(cand: Candidates) -> FloatArray:
        nonlocal done
        try:
            e = score_candidates(train, cand, base.T, progress, done, total)
        except Interrupted as i:
            raise Interrupted(objective(i.scored, train)) from None
        done += steps_all * cand["i_c"].shape[0]
        return objective(e, train)

    def runs(
        sets: Sequence[HdrParams],
    ) -> tuple[list[list[DriveResult]], list[list[DriveResult]]]:
        def run(drives: list[PreparedDrive], p: HdrParams) -> list[DriveResult]:
            return [evaluate_prepared(d, ("none", "hdr"), MethodSetup(hdr=p)) for d in drives]

        return [run(train, p) for p in sets], [run(test, p) for p in sets]

    return search_outcome(
        score,
        n_candidates,
        seed,
        base,
        runs,
        ranges=ranges,
        refine_fraction=refine_fraction,
        refine_rounds=refine_rounds,
        top_k=top_k,
    )


def params_yaml(params: HdrParams, comment: Sequence[str] = ()) -> str:
    """The ``hdr:`` section of an hdrd config (config/hdrd.yaml) holding these parameters."""
    import yaml

    body = {"hdr": {"method": "hdr", **{k: float(getattr(params, k)) for k in PARAM_NAMES}}}
    head = "".join(f"# {c}\n" for c in comment)
    return head + yaml.safe_dump(body, sort_keys=False)


def _cell(s: Summary | None, method: str) -> str:
    if s is None:
        return f"{'-':>8} {'-':>8} {'-':>17}"
    imp = s.improvement_of[method]
    imp_s = (
        "-"
        if method == "none"
        else f"{imp[0]:.2f}x" + (f" (σ {imp[1]:.2f})" if math.isfinite(imp[1]) else "")
    )
    return f"{s.ne_psi[method]:>8.3f} {s.e_psi[method]:>8.2f} {imp_s:>17}"


def format_report(r: TuneResult, seconds: float | None = None) -> str:
    """Training and test side by side, the paper's Table III set as the baseline row."""
    n_tr = len(r.train["baseline"])
    n_te = len(r.test["baseline"])
    lines = []
    took = f", {seconds:.1f} s" if seconds is not None else ""
    lines.append(
        f"HDR tuning: {r.n_evaluated} parameter sets (seed {r.seed}), "
        f"{n_tr} training drive(s), {n_te} test drive(s){took}"
    )
    lines.append("")
    lines.append(f"{'parameters':<18}" + "".join(f"{k:>9}" for k in PARAM_NAMES))
    for label, p in (("paper Table III", r.baseline), ("tuned", r.best)):
        lines.append(f"{label:<18}" + "".join(f"{getattr(p, k):>9.4g}" for k in PARAM_NAMES))
    lines.append("")
    half = f"{'NEpsi':>8} {'Epsi':>8} {'improvement':>17}"
    lines.append(f"{'':<18}{'training (' + str(n_tr) + ')':^36} | {'test (' + str(n_te) + ')':^36}")
    lines.append(f"{'':<18}{half} | {half}")
    rows = (
        ("without HDR", "baseline", "none"),
        ("paper Table III", "baseline", "hdr"),
        ("tuned", "tuned", "hdr"),
    )
    for label, which, method in rows:
        tr = r.summary("train", which)
        te = r.summary("test", which)
        lines.append(f"{label:<18}{_cell(tr, method)} | {_cell(te, method)}")
    lines.append("")
    lines.append(
        "NEpsi: mean over drives, deg/min (the objective, training); Epsi: mean, deg; "
        "improvement: mean of per-drive Epsi ratios (σ: sample std)"
    )
    lines.append(
        "the paper (Table III set): 9.2x on its nine training drives, 6.9x on five test drives"
    )
    return "\n".join(lines)


def to_json(r: TuneResult, seconds: float | None = None) -> dict[str, Any]:
    """The tuning result as plain JSON data (means per split and row, per-drive NEψ)."""

    def block(which: str) -> dict[str, Any] | None:
        res = r.train if which == "train" else r.test
        if not res["baseline"]:
            return None
        out: dict[str, Any] = {"drives": [d.name for d in res["baseline"]]}
        for label, key, method in (
            ("none", "baseline", "none"),
            ("baseline", "baseline", "hdr"),
            ("tuned", "tuned", "hdr"),
        ):
            s = summarize(res[key])
            imp, std = s.improvement_of[method]
            out[label] = {
                "mean_NE_psi": s.ne_psi[method],
                "mean_E_psi": s.e_psi[method],
                "improvement": imp if math.isfinite(imp) else None,
                "improvement_std": std if math.isfinite(std) else None,
                "NE_psi": [d.ne_psi[method] for d in res[key]],
            }
        return out

    return {
        "seed": r.seed,
        "candidates": r.n_evaluated,
        "seconds": seconds,
        "params": {
            "baseline": {k: getattr(r.baseline, k) for k in PARAM_NAMES},
            "tuned": {k: getattr(r.best, k) for k in PARAM_NAMES},
        },
        "objective": {"baseline": r.objective_baseline, "tuned": r.objective_best},
        "train": block("train"),
        "test": block("test"),
    }


def interrupted_json(e: Interrupted, base: HdrParams, seed: int, asked: int) -> dict[str, Any]:
    """What an interrupted tuning writes as its JSON: :func:`to_json`'s keys, with the best
    set so far as ``tuned``, ``"interrupted": true``, and no evaluated drives."""
    best = e.best(base)
    scored = 0 if e.cand is None else int(e.scored.shape[0])
    return {
        "interrupted": True,
        "seed": seed,
        "candidates": scored,
        "candidates_asked": asked,
        "seconds": None,
        "params": {
            "baseline": {k: getattr(base, k) for k in PARAM_NAMES},
            "tuned": {k: getattr(best[0], k) for k in PARAM_NAMES} if best else None,
        },
        "objective": {
            "baseline": float(e.scored[0]) if scored else None,
            "tuned": best[1] if best else None,
        },
        "train": None,
        "test": None,
    }


def content_key(d: PreparedDrive) -> str:
    """A digest of what tuning sees of a drive (its steps' inputs and times, its truth and
    alignment): the same drive under two names, or in two formats, has the same key."""
    import hashlib

    h = hashlib.blake2b(digest_size=16)
    st = d.steps
    for a in (st.u, st.t_end, st.n_samples, st.speed, st.temp_c, st.omega_std, d.truth):
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes() + b"|")
    h.update(repr((st.T, st.bias_dps, d.k, d.duration_min, d.start_s)).encode())
    return h.hexdigest()


SHOWN_OVERLAPS = 3
"""Test drives named in the error of an overlap (the others counted)."""


def check_held_out(train: Sequence[tuple[str, str]], test: Sequence[tuple[str, str]]) -> None:
    """EvaluationError if a test drive is also a training drive, by content
    (:func:`content_key`; each drive given as (name, key)): the test column would claim a
    held-out score it is not."""
    seen = {key: name for name, key in train}
    both = [(name, seen[key]) for name, key in test if key in seen]
    if not both:
        return
    shown = ", ".join(
        name if name == other else f"{name} (training drive {other})"
        for name, other in both[:SHOWN_OVERLAPS]
    )
    more = f" and {len(both) - SHOWN_OVERLAPS} more" if len(both) > SHOWN_OVERLAPS else ""
    raise EvaluationError(
        f"{len(both)} of the {len(test)} test drives are training drives too (the same data): "
        f"{shown}{more}; a test drive must be held out of the training"
    )
