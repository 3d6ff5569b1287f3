"""Which significant candidate to add: deterministic before stochastic, the nested special
case before its general form, the rivals the data cannot tell apart, and the backward
revisions of earlier choices (docs/model-gap.md, sections 5 and 6). Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from hdrd.analysis.gap.candidates import (
    ALPHA,
    BIC_MARGIN,
    DETERMINISTIC,
    SLOW_NOISE,
    Candidate,
)
from hdrd.analysis.gap.diagnose import correlation
from hdrd.analysis.gap.fit import Fit, Fitter
from hdrd.analysis.gap.optimize import chi2_sf
from hdrd.sim.effects import BiasInstability, Effect, RateRandomWalk, ScaleAsymmetry, ScaleFactor
from hdrd.sim.gyro import GyroModel

__all__ = [
    "AMBIGUITY_BIC",
    "AMBIGUITY_R",
    "NESTS",
    "Beyond",
    "rank",
    "revise",
    "rivals",
    "special_case",
]

AMBIGUITY_BIC = 10.0
"""A significant candidate whose BIC is within this of the best one's is a rival..."""

AMBIGUITY_R = 0.8
"""...if, for two deterministic effects, their fitted contributions to the block residual
correlate at least this much (|r|): they explain the same disagreement in the same way."""

NESTS = {("scale_asymmetry", "scale_factor"), ("bias_instability", "rate_random_walk")}
"""(general, special case): pos = neg = error; a Gauss-Markov bias whose correlation time
exceeds the log is a random walk (sigma**2 / tau_c = K**2 / 2)."""


@dataclass(frozen=True)
class Beyond:
    """A deterministic candidate tested on top of the significant slow random processes
    (``background``): does it still lower BIC by more than the margin, at p < ALPHA?"""

    background: tuple[str, ...]
    delta_bic: float
    p_value: float

    @property
    def holds(self) -> bool:
        return self.delta_bic < -BIC_MARGIN and self.p_value < ALPHA

    def row(self) -> dict[str, Any]:
        return {
            "background": list(self.background),
            "delta_bic": round(self.delta_bic, 2),
            "p_value": float(f"{self.p_value:.3g}"),
            "holds": self.holds,
        }


def _prefer_special(group: list[Candidate]) -> list[Candidate]:
    """``group`` sorted by BIC, a general form moved behind its nested special case unless it
    beats it by the margin (its extra parameter must be as significant as a new effect)."""
    out = sorted(group, key=lambda c: c.fit.bic)
    for c in list(out):
        for s in out:
            if (c.name, s.name) in NESTS and s.fit.bic - c.fit.bic < BIC_MARGIN:
                out.remove(c)
                out.insert(out.index(s) + 1, c)
                break
    return out


def rank(f: Fitter, cur: Fit, sig: list[Candidate]) -> tuple[list[Candidate], dict[str, Beyond]]:
    """The significant candidates in the order they are tried, and for each deterministic one
    whether it holds beyond the slow random processes.

    Deterministic before stochastic: a candidate read against a measured regressor comes
    first if it still lowers BIC significantly once every significant slow random process
    (bias instability, random walk; with them the ADC's quantization when significant) is in
    the model, all jointly refitted: a random process
    can imitate any slow drift, a temperature slope cannot imitate a random walk. One that
    does not hold is not tried at this step (the random process goes first; it is tried again
    at the next). Then the others (noise, quantization, low-pass) by BIC."""
    det = [c for c in sig if c.name in DETERMINISTIC]
    slow = [c for c in sig if c.name in SLOW_NOISE]
    beyond: dict[str, Beyond] = {}
    det_ok = det
    if det and slow:
        # The ADC's step, when the log shows one, is in the background too: a quantizer that
        # its noise does not dither leaves a staircase that only a random process could
        # otherwise imitate.
        slow += [c for c in sig if c.name == "quantization"]
        det_ok = _beyond_slow_noise(f, cur, det, slow, beyond)
    others = [c for c in sig if c.name not in DETERMINISTIC]
    return _prefer_special(det_ok) + _prefer_special(others), beyond


def _beyond_slow_noise(
    f: Fitter, cur: Fit, det: list[Candidate], slow: list[Candidate], beyond: dict[str, Beyond]
) -> list[Candidate]:
    """The deterministic candidates that still hold with every significant slow random
    process in the model, all jointly refitted; each one's test is put in ``beyond``."""
    model = cur.model
    for c in slow:
        e = c.fit.model.get(c.name)
        if e is not None:
            model = model.with_effect(e)
    bg = f.full(model, quad=cur.quad, extra_var=cur.noise.extra_var)
    names = tuple(c.name for c in slow)
    det_ok = []
    for c in det:
        e = c.fit.model.get(c.name)
        if e is None:
            continue
        both = f.full(bg.model.with_effect(e), quad=c.fit.quad, extra_var=bg.noise.extra_var)
        dlnl = both.lnl - bg.lnl
        p = chi2_sf(2.0 * dlnl, max(both.k - bg.k, 1)) if dlnl > 0 else 1.0
        beyond[c.name] = Beyond(background=names, delta_bic=both.bic - bg.bic, p_value=p)
        if beyond[c.name].holds:
            det_ok.append(c)
    return det_ok


def _slow_gm(a: Candidate, duration_s: float) -> bool:
    gm = a.fit.model.get("bias_instability")
    return isinstance(gm, BiasInstability) and gm.tau_s >= duration_s


def rivals(
    best: Candidate, others: list[Candidate], duration_s: float
) -> list[tuple[Candidate, float | None]]:
    """Significant candidates the data cannot tell from ``best`` (documented rule)."""
    out: list[tuple[Candidate, float | None]] = []
    for c in others:
        if c.name == best.name or not c.significant or "quantization" in (c.name, best.name):
            continue
        if (c.name, best.name) in NESTS:
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
        elif (best.name in DETERMINISTIC) != (c.name in DETERMINISTIC):
            continue  # deterministic before stochastic decided between these two
        out.append((c, r))
    return out


def special_case(e: Effect) -> Effect | None:
    """The nested special case an effect can be simplified to (same physics, fewer parameters)."""
    if isinstance(e, ScaleAsymmetry):
        return ScaleFactor(error=0.5 * (e.pos_error + e.neg_error))
    if isinstance(e, BiasInstability):
        return RateRandomWalk(k_dps_per_sqrt_s=e.sigma_dps * math.sqrt(2.0 / e.tau_s))
    return None


def revise(f: Fitter, cur: Fit, added: list[str], step: int) -> list[tuple[Fit, dict[str, Any]]]:
    """Backward elimination after a step: the effects added earlier that are no longer
    strongly supported now that the new one explains part of their disagreement, each
    simplified to its nested special case or dropped (whichever has the lower BIC) if that
    costs less than :data:`BIC_MARGIN` of BIC; best (lowest BIC) first. The caller makes the
    first change that does not raise the gap."""
    best: dict[str, tuple[Fit, dict[str, Any]]] = {}
    for name in added[:-1]:
        e = cur.model.get(name)
        if e is None:
            continue
        alts: list[tuple[str, GyroModel]] = [("dropped", cur.model.without(name))]
        sc = special_case(e)
        if sc is not None and sc.name not in cur.model:
            alts.append((f"replaced by {sc.name}", cur.model.without(name).with_effect(sc)))
        for how, m in alts:
            alt = f.full(m, quad=cur.quad, extra_var=cur.noise.extra_var)
            cost = alt.bic - cur.bic
            if cost < BIC_MARGIN and (name not in best or alt.bic < best[name][0].bic):
                rec = {
                    "after_step": step,
                    "effect": name,
                    "action": how,
                    "delta_bic": round(cost, 2),
                    "why": f"{name} no longer lowers BIC by more than {BIC_MARGIN:g} once the later effects are in",
                }
                best[name] = (alt, rec)
    return sorted(best.values(), key=lambda x: x[0].bic)
