"""The model-gap loop: add the preferred significant candidate unless it raises the gap,
report rivals, refit jointly, revise earlier choices, until nothing significant is left
(docs/model-gap.md). Pure.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hdrd.analysis.gap.bounds import params_at_bounds
from hdrd.analysis.gap.candidates import (
    CANDIDATES,
    SLOW_NOISE,
    Candidate,
    evaluate_candidate,
    not_identifiable,
    slow_noise_forms,
)
from hdrd.analysis.gap.choose import AMBIGUITY_BIC, Beyond, rank, revise, rivals
from hdrd.analysis.gap.data import GapData, GapError, moving_indicator, prepare
from hdrd.analysis.gap.diagnose import REGRESSOR, diagnostics, where_phrase
from hdrd.analysis.gap.fit import Fit, Fitter, fit_model
from hdrd.analysis.gap.metric import GapMeasure, gap_metric
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.effects import EFFECTS, Effect
from hdrd.sim.gyro import DEFAULT_START_MODEL, GyroModel

__all__ = [
    "GAP_NOISE_SEEDS",
    "MAX_STEPS",
    "Ambiguity",
    "GapResult",
    "Step",
    "run_gap",
    "sig4",
]

MAX_STEPS = 8
FORM_GAP_RATIO = 0.8
FORM_GAP_DROP = 0.05
GAP_NOISE_SEEDS = 6
"""Seeds over which the final gap is re-measured to state its seed-to-seed noise."""


@dataclass(frozen=True)
class Ambiguity:
    """Effects the data could not tell apart at a step."""

    step: int
    effects: tuple[str, ...]
    chosen: str
    delta_bic: tuple[float, ...]
    """BIC of each rival minus the chosen one's."""
    contribution_r: tuple[float | None, ...]
    note: str


@dataclass(frozen=True)
class Step:
    """One accepted effect."""

    effect: str
    params: dict[str, float]
    where: str
    gap_before: float
    gap_after: float
    delta_bic: float
    p_value: float
    ambiguous_with: tuple[str, ...]
    candidates: tuple[dict[str, Any], ...]
    diagnostics: dict[str, Any]
    regressor: str
    at_bound: tuple[dict[str, Any], ...]
    """Parameters of the model after the step that sit at a fit bound."""
    gap_over_seeds: tuple[float, float, float] | None
    """When the first seed's gap rose with the effect: the gap before and after, each the
    mean over :data:`GAP_NOISE_SEEDS` seeds (the same seeds), and the seed-to-seed sd of the
    gap before, which decided (the rise was within it); else None."""
    fit_before: Fit = field(repr=False)
    fit_after: Fit = field(repr=False)
    sim_before: GapMeasure = field(repr=False)
    sim_after: GapMeasure = field(repr=False)


@dataclass(frozen=True)
class GapResult:
    """Everything :func:`run_gap` found; :func:`to_report` turns it into the report JSON."""

    data: GapData
    initial_model: GyroModel
    initial_fit: Fit
    initial_sim: GapMeasure
    gap_as_given: float
    steps: tuple[Step, ...]
    final_fit: Fit
    final_sim: GapMeasure
    remaining: tuple[dict[str, Any], ...]
    ambiguous: tuple[Ambiguity, ...]
    revisions: tuple[dict[str, Any], ...]
    not_identifiable: dict[str, str]
    final_diagnostics: dict[str, Any]
    rejected: tuple[dict[str, Any], ...]
    """Significant candidates not added because the gap rose with them."""
    final_at_bound: tuple[dict[str, Any], ...]
    gap_noise: dict[str, Any]
    """The final gap re-measured with other seeds: its seed-to-seed spread."""
    final_standard_errors: dict[str, dict[str, float]] = field(default_factory=dict)
    """Standard errors of the final model's deterministic parameters by effect and
    parameter (:meth:`Fitter.standard_errors`; the static bias left out)."""

    @property
    def final_model(self) -> GyroModel:
        return self.final_fit.model


def _cand_row(c: Candidate, beyond: Beyond | None = None) -> dict[str, Any]:
    eff = c.fit.model.get(c.name)
    row = {
        "effect": c.name,
        "delta_bic": round(c.dbic, 2),
        "delta_loglik": round(c.dlnl, 2),
        "p_value": float(f"{c.p:.3g}"),
        "significant": c.significant,
        "params": _params(eff) if eff is not None else {},
    }
    if beyond is not None:
        row["beyond_random_processes"] = beyond.row()
    return row


def _params(e: Effect) -> dict[str, float]:
    return {k: float(f"{v:.6g}") for k, v in e.params().items()}


def _ambiguity(step: int, best: Candidate, rv: list[tuple[Candidate, float | None]]) -> Ambiguity:
    names_r = tuple(c.name for c, _ in rv)
    return Ambiguity(
        step=step,
        effects=(best.name, *names_r),
        chosen=best.name,
        delta_bic=tuple(round(c.fit.bic - best.fit.bic, 2) for c, _ in rv),
        contribution_r=tuple(None if r is None else round(r, 3) for _, r in rv),
        note=(
            f"{best.name} and {', '.join(names_r)} explain this disagreement about "
            f"equally well (BIC within {AMBIGUITY_BIC:g}); {best.name} was added "
            "because its BIC is lowest, but the log cannot tell them apart"
        ),
    )


def _seed_gaps(data: GapData, fit: Fit, seed: int, gap: float) -> list[float]:
    """The gap of ``fit`` over :data:`GAP_NOISE_SEEDS` seeds: ``gap`` (the first seed's),
    then seeds seed + 1000 + j."""
    return [gap] + [
        gap_metric(data, fit.model, seed + 1000 + j, fit.d, fit.noise.extra_var).gap
        for j in range(GAP_NOISE_SEEDS - 1)
    ]


def _gap_noise(data: GapData, fit: Fit, seed: int, gap: float) -> dict[str, Any]:
    gaps = _seed_gaps(data, fit, seed, gap)
    mean = sum(gaps) / len(gaps)
    sd = math.sqrt(sum((g - mean) ** 2 for g in gaps) / (len(gaps) - 1))
    return {
        "seeds": len(gaps),
        "gap_final_mean": sig4(mean),
        "gap_final_sd": sig4(sd),
        "gap_final_range": [sig4(min(gaps)), sig4(max(gaps))],
    }


def _slow_form(
    f: Fitter, cur: Fit, cur_sim: GapMeasure, seed: int, step: int
) -> tuple[Fit, GapMeasure, dict[str, Any] | None]:
    """If the model has slow noise: of its forms (random walk, bias instability, both) whose
    BIC is within :data:`AMBIGUITY_BIC` of the best, the one with the lowest gap, if that
    gap is clearly lower (below :data:`FORM_GAP_RATIO` times the current one and by more
    than :data:`FORM_GAP_DROP`, beyond the gap's seed-to-seed noise)."""
    if not any(s in cur.model for s in SLOW_NOISE):
        return cur, cur_sim, None
    data = f.data
    forms = [cur, *slow_noise_forms(f, cur)]
    best_bic = min(x.bic for x in forms)
    close = [x for x in forms if x.bic - best_bic < AMBIGUITY_BIC]
    scored = [
        (
            cur_sim.gap
            if x is cur
            else gap_metric(data, x.model, seed, x.d, x.noise.extra_var).gap,
            i,
            x,
        )
        for i, x in enumerate(close)
    ]
    gap, _, x = min(scored, key=lambda z: (z[0], z[1]))
    names = _slow_names(x)
    old = _slow_names(cur)
    if (
        x is cur
        or names == old
        or not (gap < FORM_GAP_RATIO * cur_sim.gap and cur_sim.gap - gap > FORM_GAP_DROP)
    ):
        return cur, cur_sim, None
    rec = {
        "after_step": step,
        "effect": " + ".join(old),
        "action": f"replaced by {' + '.join(names)}",
        "delta_bic": round(x.bic - cur.bic, 2),
        "why": (
            f"the block likelihood cannot tell these forms of the slow noise apart (BIC within "
            f"{AMBIGUITY_BIC:g}: {', '.join(' + '.join(_slow_names(y)) for y in close)}); "
            "the Allan deviation over all tau can: the one with the lowest gap is kept"
        ),
    }
    return x, gap_metric(data, x.model, seed, x.d, x.noise.extra_var), rec


def _slow_names(fit: Fit) -> list[str]:
    """The slow-noise effects of a fit's model, in the model's order."""
    return [n for n in fit.model.names() if n in SLOW_NOISE]


def _rejection(
    step: int,
    best: Candidate,
    gap_before: float,
    gap_with_it: float,
    over: tuple[float, float, float],
) -> dict[str, Any]:
    """The record of a significant effect rejected because the gap rose with it."""
    return {
        "step": step,
        "effect": best.name,
        "delta_bic": round(best.dbic, 2),
        "gap_before": sig4(gap_before),
        "gap_with_it": sig4(gap_with_it),
        "gap_over_seeds": [sig4(over[0]), sig4(over[1]), sig4(over[2])],
        "why": "significant, but the gap rose with it, also as the mean "
        f"over {GAP_NOISE_SEEDS} seeds by more than its seed-to-seed sd: "
        "the fitted effect makes the simulated log less like the measured "
        "one",
    }


_Chosen = tuple[Candidate, Fit, GapMeasure, tuple[float, float, float] | None]
"""A step's choice: the candidate, its joint refit and that fit's gap, and the gap before and
after over seeds when the first seed's gap rose (:attr:`Step.gap_over_seeds`)."""


class _Search:
    """The forward search of :func:`run_gap`: the current fit and its gap, and what the
    steps record (the steps, rivals, the last step's candidates, revisions, rejections)."""

    def __init__(
        self, f: Fitter, seed: int, cur: Fit, cur_sim: GapMeasure, skip: dict[str, str]
    ) -> None:
        self.f, self.data, self.seed = f, f.data, seed
        self.cur, self.cur_sim = cur, cur_sim
        self.skip = skip
        self.steps: list[Step] = []
        self.ambiguous: list[Ambiguity] = []
        self.remaining: list[dict[str, Any]] = []
        self.added: list[str] = []
        self.dropped: set[str] = set()  # revised away: never re-added (no loops)
        self.revisions: list[dict[str, Any]] = []
        self.rejected: list[dict[str, Any]] = []

    def step(self, n: int, candidates: Sequence[str]) -> bool:
        """Step ``n`` (from 1): add the preferred significant candidate that does not raise
        the gap, then revise; False when there is none."""
        f, cur = self.f, self.cur
        names = [
            c
            for c in candidates
            if c not in cur.model and c not in self.skip and c not in self.dropped
        ]
        cands = [evaluate_candidate(f, cur, c) for c in names]
        sig = [c for c in cands if c.significant]
        order, beyond = rank(f, cur, sig)
        rows = tuple(_cand_row(c, beyond.get(c.name)) for c in sorted(cands, key=lambda c: c.dbic))
        self.remaining = list(rows)
        chosen = self._first_kept(order, n)
        if chosen is None:
            return False
        self._add(n, chosen, [c for c in cands if c in order], rows)
        self._revise(n)
        self.cur, self.cur_sim, form = _slow_form(f, self.cur, self.cur_sim, self.seed, n)
        if form is not None:
            form["gap_after"] = sig4(self.cur_sim.gap)
            self.revisions.append(form)
        return True

    def _trial(self, c: Candidate) -> tuple[Fit, GapMeasure]:
        """The candidate's model jointly refitted, and its gap."""
        new = self.f.full(c.fit.model, quad=c.fit.quad, extra_var=c.fit.noise.extra_var)
        if new.lnl < c.fit.lnl:
            new = c.fit  # the joint refit can only keep or improve the candidate's fit
        return new, gap_metric(self.data, new.model, self.seed, new.d, new.noise.extra_var)

    def _quantization_by_gap(
        self, order: list[Candidate], trials: dict[str, tuple[Fit, GapMeasure]]
    ) -> list[Candidate]:
        """Quantization's BIC is the lattice's, on another scale than the other candidates':
        it goes first when its refit closes more of the gap than that of the candidate the
        rules put first (the effect named first is the one that closes most of the gap),
        else where its BIC puts it."""
        q = next((c for c in order if c.name == "quantization"), None)
        if q is None or order[0] is q:
            return order
        for c in (order[0], q):
            trials[c.name] = self._trial(c)
        if trials[q.name][1].gap < trials[order[0].name][1].gap:
            return [q, *(c for c in order if c is not q)]
        return order

    def _first_kept(self, order: list[Candidate], n: int) -> _Chosen | None:
        """The first candidate in order (quantization placed by the gap it closes) whose
        joint refit does not raise the gap (beyond the gap's seed-to-seed noise); those that
        do are recorded as rejected."""
        data, seed, cur, cur_sim = self.data, self.seed, self.cur, self.cur_sim
        cur_seeds: list[float] | None = None
        trials: dict[str, tuple[Fit, GapMeasure]] = {}
        for best in self._quantization_by_gap(order, trials):
            new, new_sim = trials[best.name] if best.name in trials else self._trial(best)
            over: tuple[float, float, float] | None = None
            if new_sim.gap > cur_sim.gap:
                # One seed's gap differs from the next by its seed-to-seed noise, and a gap
                # difference smaller than that says nothing: the same seeds decide, averaged,
                # and the effect is rejected if the gap rises by more than its noise.
                if cur_seeds is None:
                    cur_seeds = _seed_gaps(data, cur, seed, cur_sim.gap)
                new_seeds = _seed_gaps(data, new, seed, new_sim.gap)
                over = (
                    statistics.mean(cur_seeds),
                    statistics.mean(new_seeds),
                    statistics.stdev(cur_seeds),
                )
                if over[1] - over[0] > over[2]:
                    self.rejected.append(_rejection(n, best, cur_sim.gap, new_sim.gap, over))
                    continue
            return best, new, new_sim, over
        return None

    def _add(
        self,
        n: int,
        chosen: _Chosen,
        ranked: list[Candidate],
        rows: tuple[dict[str, Any], ...],
    ) -> None:
        """Take the chosen candidate as step ``n``: its record, its rivals among the ranked
        candidates; it becomes the current fit."""
        best, new, new_sim, over = chosen
        data, cur, cur_sim = self.data, self.cur, self.cur_sim
        rv = rivals(best, ranked, data.duration_s)
        diag = diagnostics(data, cur, cur_sim)
        if rv:
            self.ambiguous.append(_ambiguity(n, best, rv))
        eff = new.model.get(best.name)
        self.steps.append(
            Step(
                effect=best.name,
                params=_params(eff) if eff is not None else {},
                where=where_phrase(data, best, cur_sim, diag, rows, self.skip, self.rejected),
                gap_before=cur_sim.gap,
                gap_after=new_sim.gap,
                delta_bic=best.dbic,
                p_value=best.p,
                ambiguous_with=tuple(c.name for c, _ in rv),
                candidates=rows,
                diagnostics=diag,
                regressor=REGRESSOR.get(best.name, "time_s"),
                at_bound=tuple(params_at_bounds(new.model, data)),
                gap_over_seeds=over,
                fit_before=cur,
                fit_after=new,
                sim_before=cur_sim,
                sim_after=new_sim,
            )
        )
        self.cur, self.cur_sim = new, new_sim
        self.added.append(best.name)

    def _revise(self, n: int) -> None:
        """Revise the earlier choices (:func:`revise`) one at a time while one is found that
        does not raise the gap."""
        added = self.added
        for _ in range(len(added)):
            made = False
            for revised, rec in revise(self.f, self.cur, added, n):
                rsim = gap_metric(
                    self.data, revised.model, self.seed, revised.d, revised.noise.extra_var
                )
                if rsim.gap > self.cur_sim.gap:
                    continue  # a revision must not raise the gap either
                added.remove(rec["effect"])
                self.dropped.add(rec["effect"])
                if rec["action"].startswith("replaced by "):
                    added.append(rec["action"][len("replaced by ") :])
                self.cur, self.cur_sim = revised, rsim
                rec["gap_after"] = sig4(self.cur_sim.gap)
                self.revisions.append(rec)
                made = True
                break
            if not made:
                break


def run_gap(
    log: DriveLog | GapData,
    start: GyroModel = DEFAULT_START_MODEL,
    *,
    standstill: bool = False,
    exclude: Sequence[tuple[float, float]] = (),
    seed: int = 0,
    candidates: Sequence[str] = CANDIDATES,
    max_steps: int = MAX_STEPS,
) -> GapResult:
    """Run the model-gap workflow on a measured log from the model ``start``; ``exclude``:
    periods (T0, T1) of the log's own t (s) left out, besides rows marked ``valid`` = 0.

    Deterministic for a seed (it only seeds the model simulations of the gap metric)."""
    data = log if isinstance(log, GapData) else prepare(log, standstill, exclude=exclude)
    unknown = [c for c in candidates if c not in EFFECTS]
    if unknown:
        raise GapError(f"unknown candidate effect(s): {', '.join(unknown)}")
    if "motion_offset" in start and moving_indicator(data) is None:
        raise GapError("the model has motion_offset, which needs the log's speed: it has none")
    f = Fitter(data)
    cur = fit_model(data, start)
    sim_given = gap_metric(data, start, seed, None, cur.noise.extra_var)
    cur_sim = gap_metric(data, cur.model, seed, cur.d, cur.noise.extra_var)
    s = _Search(f, seed, cur, cur_sim, not_identifiable(data, cur.model))
    for i in range(max_steps):
        if not s.step(i + 1, candidates):
            break
    return GapResult(
        data=data,
        initial_model=start,
        initial_fit=cur,
        initial_sim=cur_sim,
        gap_as_given=sim_given.gap,
        steps=tuple(s.steps),
        final_fit=s.cur,
        final_sim=s.cur_sim,
        remaining=tuple(s.remaining),
        ambiguous=tuple(s.ambiguous),
        revisions=tuple(s.revisions),
        not_identifiable=s.skip,
        final_diagnostics=diagnostics(data, s.cur, s.cur_sim),
        rejected=tuple(s.rejected),
        final_at_bound=tuple(params_at_bounds(s.cur.model, data)),
        gap_noise=_gap_noise(data, s.cur, seed, s.cur_sim.gap),
        final_standard_errors=f.standard_errors(s.cur),
    )


def sig4(x: float) -> float:
    return float(f"{x:.4g}")
