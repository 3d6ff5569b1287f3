"""The model-gap loop: add the best significant candidate, report rivals, refit, revise
earlier choices, until nothing significant is left (docs/model-gap.md). Pure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hdrd.analysis.gap.candidates import (
    BIC_MARGIN,
    CANDIDATES,
    Candidate,
    evaluate_candidate,
    not_identifiable,
)
from hdrd.analysis.gap.data import GapData, GapError, prepare
from hdrd.analysis.gap.diagnose import REGRESSOR, correlation, diagnostics, where_phrase
from hdrd.analysis.gap.fit import Fit, Fitter, fit_model
from hdrd.analysis.gap.metric import GapMeasure, gap_metric
from hdrd.drivelog import DriveLog
from hdrd.sim.gyro import (
    DEFAULT_START_MODEL,
    EFFECTS,
    BiasInstability,
    Effect,
    GyroModel,
    RateRandomWalk,
    ScaleAsymmetry,
    ScaleFactor,
)

__all__ = [
    "AMBIGUITY_BIC",
    "AMBIGUITY_R",
    "MAX_STEPS",
    "Ambiguity",
    "GapResult",
    "Step",
    "run_gap",
    "sig4",
]

AMBIGUITY_BIC = 10.0
"""A significant candidate whose BIC is within this of the best one's is a rival..."""

AMBIGUITY_R = 0.8
"""...if, for two deterministic effects, their fitted contributions to the block residual
correlate at least this much (|r|): they explain the same disagreement in the same way."""

MAX_STEPS = 8

# (general, special case): pos = neg = error; a Gauss-Markov bias whose correlation time
# exceeds the log is a random walk (sigma**2 / tau_c = K**2 / 2).
_NESTS = {("scale_asymmetry", "scale_factor"), ("bias_instability", "rate_random_walk")}


def _slow_gm(a: Candidate, duration_s: float) -> bool:
    gm = a.fit.model.get("bias_instability")
    return isinstance(gm, BiasInstability) and gm.tau_s >= duration_s


def _rivals(
    best: Candidate, others: list[Candidate], duration_s: float
) -> list[tuple[Candidate, float | None]]:
    """Significant candidates the data cannot tell from ``best`` (documented rule)."""
    out: list[tuple[Candidate, float | None]] = []
    for c in others:
        if c.name == best.name or not c.significant or "quantization" in (c.name, best.name):
            continue
        if (c.name, best.name) in _NESTS:
            continue  # the general form adds nothing the special case lacks: parsimony decides
        if (best.name, c.name) == ("bias_instability", "rate_random_walk") and _slow_gm(
            best, duration_s
        ):
            out.append((c, None))  # a Gauss-Markov bias slower than the log is a random walk
            continue
        if c.fit.bic - best.fit.bic >= AMBIGUITY_BIC:
            continue
        r: float | None = None
        if best.contribution is not None and c.contribution is not None:
            r = correlation(best.contribution, c.contribution)
            if abs(r) < AMBIGUITY_R:
                continue  # both real, explaining different parts: later steps add the other
        out.append((c, r))
    return out


def _special_case(e: Effect) -> Effect | None:
    """The nested special case an effect can be simplified to (same physics, fewer parameters)."""
    if isinstance(e, ScaleAsymmetry):
        return ScaleFactor(error=0.5 * (e.pos_error + e.neg_error))
    if isinstance(e, BiasInstability):
        return RateRandomWalk(k_dps_per_sqrt_s=e.sigma_dps * math.sqrt(2.0 / e.tau_s))
    return None


def _revise(f: Fitter, cur: Fit, added: list[str], step: int) -> tuple[Fit, list[dict[str, Any]]]:
    """Backward check after a step: an effect added earlier that is no longer strongly
    supported now that the new one explains part of its disagreement is simplified to its
    nested special case or dropped (whichever has the lower BIC), if that costs less than
    :data:`BIC_MARGIN` of BIC. One change per call."""
    best: tuple[float, Fit, dict[str, Any]] | None = None
    for name in added[:-1]:
        e = cur.model.get(name)
        if e is None:
            continue
        alts: list[tuple[str, GyroModel]] = [("dropped", cur.model.without(name))]
        sc = _special_case(e)
        if sc is not None and sc.name not in cur.model:
            alts.append((f"replaced by {sc.name}", cur.model.without(name).with_effect(sc)))
        for how, m in alts:
            alt = f.full(m, quad=cur.quad, extra_var=cur.noise.extra_var)
            cost = alt.bic - cur.bic
            if cost < BIC_MARGIN and (best is None or alt.bic < best[0]):
                rec = {
                    "after_step": step,
                    "effect": name,
                    "action": how,
                    "delta_bic": round(cost, 2),
                    "why": f"{name} no longer lowers BIC by more than {BIC_MARGIN:g} once the later effects are in",
                }
                best = (alt.bic, alt, rec)
    if best is None:
        return cur, []
    return best[1], [best[2]]


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

    @property
    def final_model(self) -> GyroModel:
        return self.final_fit.model


def _cand_row(c: Candidate) -> dict[str, Any]:
    eff = c.fit.model.get(c.name)
    return {
        "effect": c.name,
        "delta_bic": round(c.dbic, 2),
        "delta_loglik": round(c.dlnl, 2),
        "p_value": float(f"{c.p:.3g}"),
        "significant": c.significant,
        "params": _params(eff) if eff is not None else {},
    }


def _params(e: Effect) -> dict[str, float]:
    return {k: float(f"{v:.6g}") for k, v in e.params().items()}


def run_gap(
    log: DriveLog | GapData,
    start: GyroModel = DEFAULT_START_MODEL,
    *,
    standstill: bool = False,
    seed: int = 0,
    candidates: Sequence[str] = CANDIDATES,
    max_steps: int = MAX_STEPS,
) -> GapResult:
    """Run the model-gap workflow on a measured log from the model ``start``.

    Deterministic for a seed (it only seeds the model simulations of the gap metric)."""
    data = log if isinstance(log, GapData) else prepare(log, standstill=standstill)
    unknown = [c for c in candidates if c not in EFFECTS]
    if unknown:
        raise GapError(f"unknown candidate effect(s): {', '.join(unknown)}")
    f = Fitter(data)
    cur = fit_model(data, start)
    sim_given = gap_metric(data, start, seed, None, cur.noise.extra_var)
    cur_sim = gap_metric(data, cur.model, seed, cur.d, cur.noise.extra_var)
    initial_fit, initial_sim = cur, cur_sim
    skip = not_identifiable(data, cur.model)
    steps: list[Step] = []
    ambiguous: list[Ambiguity] = []
    remaining: list[Candidate] = []
    added: list[str] = []
    dropped: set[str] = set()  # revised away: never re-added (no loops)
    revisions: list[dict[str, Any]] = []
    for i in range(max_steps):
        names = [c for c in candidates if c not in cur.model and c not in skip and c not in dropped]
        cands = [evaluate_candidate(f, cur, c) for c in names]
        sig = [c for c in cands if c.significant]
        remaining = cands
        if not sig:
            break
        best = min(sig, key=lambda c: c.fit.bic)
        for c in sig:
            # A general form must beat its special case by the same margin as any new effect.
            if (best.name, c.name) in _NESTS and c.fit.bic - best.fit.bic < BIC_MARGIN:
                best = c
        rivals = _rivals(best, cands, data.duration_s)
        diag = diagnostics(data, cur, cur_sim)
        new = f.full(best.fit.model, quad=best.fit.quad, extra_var=best.fit.noise.extra_var)
        if new.lnl < best.fit.lnl:
            new = best.fit  # the joint refit can only keep or improve the candidate's fit
        new_sim = gap_metric(data, new.model, seed, new.d, new.noise.extra_var)
        if rivals:
            names_r = tuple(c.name for c, _ in rivals)
            ambiguous.append(
                Ambiguity(
                    step=i + 1,
                    effects=(best.name, *names_r),
                    chosen=best.name,
                    delta_bic=tuple(round(c.fit.bic - best.fit.bic, 2) for c, _ in rivals),
                    contribution_r=tuple(None if r is None else round(r, 3) for _, r in rivals),
                    note=(
                        f"{best.name} and {', '.join(names_r)} explain this disagreement about "
                        f"equally well (BIC within {AMBIGUITY_BIC:g}); {best.name} was added "
                        "because its BIC is lowest, but the log cannot tell them apart"
                    ),
                )
            )
        eff = new.model.get(best.name)
        steps.append(
            Step(
                effect=best.name,
                params=_params(eff) if eff is not None else {},
                where=where_phrase(data, best, cur_sim, diag),
                gap_before=cur_sim.gap,
                gap_after=new_sim.gap,
                delta_bic=best.dbic,
                p_value=best.p,
                ambiguous_with=tuple(c.name for c, _ in rivals),
                candidates=tuple(_cand_row(c) for c in sorted(cands, key=lambda c: c.dbic)),
                diagnostics=diag,
                regressor=REGRESSOR.get(best.name, "time_s"),
                fit_before=cur,
                fit_after=new,
                sim_before=cur_sim,
                sim_after=new_sim,
            )
        )
        cur, cur_sim = new, new_sim
        added.append(best.name)
        for _ in range(len(added)):
            revised, recs = _revise(f, cur, added, i + 1)
            if not recs:
                break
            rec = recs[0]
            added.remove(rec["effect"])
            dropped.add(rec["effect"])
            if rec["action"].startswith("replaced by "):
                added.append(rec["action"][len("replaced by ") :])
            cur = revised
            cur_sim = gap_metric(data, cur.model, seed, cur.d, cur.noise.extra_var)
            rec["gap_after"] = sig4(cur_sim.gap)
            revisions.append(rec)
    return GapResult(
        data=data,
        initial_model=start,
        initial_fit=initial_fit,
        initial_sim=initial_sim,
        gap_as_given=sim_given.gap,
        steps=tuple(steps),
        final_fit=cur,
        final_sim=cur_sim,
        remaining=tuple(_cand_row(c) for c in sorted(remaining, key=lambda c: c.dbic)),
        ambiguous=tuple(ambiguous),
        revisions=tuple(revisions),
        not_identifiable=skip,
        final_diagnostics=diagnostics(data, cur, cur_sim),
    )


def sig4(x: float) -> float:
    return float(f"{x:.4g}")
