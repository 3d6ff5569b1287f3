"""Where measurement and model disagree: the discrepancy measures of the report and the
"where" sentence of each step. Pure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.candidates import Candidate
from hdrd.analysis.gap.data import GapData, moving_indicator
from hdrd.analysis.gap.fit import Fit, clipping_rail
from hdrd.analysis.gap.lowpass import pole, white_factor
from hdrd.analysis.gap.metric import GapMeasure
from hdrd.sim.effects import Bandwidth, MotionOffset, WarmupTransient

__all__ = ["REGRESSOR", "correlation", "diagnostics", "regressors", "where_phrase"]

FloatArray = npt.NDArray[np.float64]


def correlation(a: FloatArray, b: FloatArray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0


REGRESSOR = {
    "temperature_bias": "temp_c",
    "warmup_transient": "time_s",
    "motion_offset": "moving",
    "scale_factor": "true_rate",
    "scale_asymmetry": "true_rate",
    "time_offset": "rate_derivative",
    "saturation": "true_rate",
    "static_bias": "time_s",
    "bias_instability": "time_s",
    "rate_random_walk": "time_s",
    "white_noise": "time_s",
    "quantization": "omega",
}
"""The regressor each effect is read against, in the report's "where" and in the plot."""


def regressors(data: GapData) -> dict[str, FloatArray]:
    """Block means of everything the residual is compared against."""
    w = data.truth_filled
    out = {
        "time_s": data.bt[data.bvalid],
        "true_rate": data.btruth,
        "true_rate_left": data.block_mean(np.maximum(w, 0.0)),
        "true_rate_right": data.block_mean(np.minimum(w, 0.0)),
        "rate_derivative": data.block_mean(np.gradient(w, data.t)),
    }
    if data.temp_c is not None:
        out["temp_c"] = data.block_mean(data.temp_c)
    mv = moving_indicator(data)
    if mv is not None:
        out["moving"] = data.block_mean(mv)  # the share of each block driven
    return out


def diagnostics(data: GapData, fit: Fit, sim: GapMeasure) -> dict[str, Any]:
    """Discrepancy measures for the report: Allan deviation ratio over tau, correlations of
    the unexplained block residual, residual by part of the log, histogram."""
    e = data.block_residual(data.omega) - fit.dbar
    regs = regressors(data)
    corr = {
        k: round(correlation(e, v), 3)
        for k, v in regs.items()
        if k not in ("true_rate_left", "true_rate_right")
    }
    # Sign: separate slopes for left (+) and right (-) turns, least squares with a constant.
    a = np.vstack([regs["true_rate_left"], regs["true_rate_right"], np.ones_like(e)]).T
    coef, *_ = np.linalg.lstsq(a, e, rcond=None)
    parts = np.array_split(np.arange(e.shape[0]), 10)
    with np.errstate(divide="ignore", invalid="ignore"):  # no deviation at a tau: no ratio
        ratio = sim.adev_meas / sim.adev_sim
    rail = clipping_rail(data)
    at_rail = int(
        np.sum(np.abs(np.abs(data.omega) - (rail or 0.0)) <= max(data.resolution_dps, 1e-9) * 1.01)
    )
    hist: dict[str, Any] = {
        "resolution_dps": data.resolution_dps,
        "max_abs_omega_dps": rail,
        "samples_at_max": at_rail,
    }
    if data.lattice is not None:
        hist["lattice_dps"] = round(data.lattice.step_dps, 9)
        hist["lattice_offset_dps"] = round(data.lattice.offset_dps, 9)
        hist["on_lattice"] = round(data.lattice.fraction, 5)
    return {
        "allan": {
            "tau_s": [round(float(x), 4) for x in sim.taus],
            "measured_dps": [
                None if not np.isfinite(x) else float(f"{x:.4g}") for x in sim.adev_meas
            ],
            "simulated_dps": [
                None if not np.isfinite(x) else float(f"{x:.4g}") for x in sim.adev_sim
            ],
            "max_ratio": None
            if not np.isfinite(ratio).any()
            else round(float(np.nanmax(ratio)), 3),
        },
        "correlation": corr,
        "slope_left_right": [round(float(coef[0]), 5), round(float(coef[1]), 5)],
        "mean_by_tenth_dps": [
            round(float(e[p].mean() - e.mean()), 5) if p.shape[0] else None for p in parts
        ],
        "histogram": hist,
    }


def _allan_phrase(sim: GapMeasure) -> str:
    with np.errstate(divide="ignore", invalid="ignore"):
        r = sim.adev_meas / sim.adev_sim
    ok = np.isfinite(r) & (r > 0)
    if not ok.any():
        return "Allan deviation not available"
    rr, tt = r[ok], sim.taus[ok]
    hi, lo = rr > 1.5, rr < 1.0 / 1.5
    parts = []
    for sel, word, ext in (
        (hi, "up to {:.2g}x the model's, above 1.5x", float(rr.max())),
        (lo, "down to {:.2g}x the model's, below 1/1.5x", float(rr.min())),
    ):
        if sel.any():
            a, b = _fmt_tau(float(tt[sel].min())), _fmt_tau(float(tt[sel].max()))
            span = a if a == b else f"{a}-{b}"
            parts.append(f"{word.format(ext)} at tau = {span} s")
    if not parts:
        return (
            f"Allan deviation within 1.5x of the model's "
            f"({float(rr.min()):.2f}x-{float(rr.max()):.2f}x)"
        )
    return "Allan deviation " + "; ".join(parts)


def _fmt_tau(t: float) -> str:
    return f"{t:.2g}" if t < 10 else f"{t:.0f}"


_EFFECT_OF = {
    "temp_c": "temperature_bias",
    "moving": "motion_offset",
    "time_s": "warmup_transient",
    "true_rate": "scale_factor",
    "rate_derivative": "time_offset",
}
"""The deterministic effect each regressor of the diagnostics stands for."""

_STRONG_R = 0.3
"""A regressor correlating at least this much with the residual needs a word on its effect."""


def _why_not(
    effect: str,
    rows: Sequence[dict[str, Any]],
    skip: dict[str, str],
    rejected: Sequence[dict[str, Any]],
) -> str:
    """Why ``effect`` is not the one added at this step, from the step's own evidence."""
    if effect in skip:
        return f"is not identifiable here ({skip[effect]})"
    row = next((r for r in rows if r["effect"] == effect), None)
    if row is None:
        return "is already in the model"
    bey = row.get("beyond_random_processes")
    if row["significant"] and bey is not None and not bey["holds"]:
        return (
            f"does not hold once {' + '.join(bey['background'])} is in the model "
            f"(dBIC {bey['delta_bic']:+.1f}): a random process explains that drift as well"
        )
    if not row["significant"]:
        return f"is not significant (dBIC {row['delta_bic']:+.1f})"
    if any(r["effect"] == effect for r in rejected):
        return "was tried and raised the gap"
    return f"ranks lower (dBIC {row['delta_bic']:+.1f})"


def where_phrase(
    data: GapData,
    cand: Candidate,
    sim: GapMeasure,
    diag: dict[str, Any],
    rows: Sequence[dict[str, Any]] = (),
    skip: dict[str, str] | None = None,
    rejected: Sequence[dict[str, Any]] = (),
) -> str:
    """What disagreed, in words, for the effect that explains it. For a random effect the
    regressor that correlates most with the residual is named with the reason its own effect
    was not chosen (``rows``: the step's candidates; ``skip``: the effects not identifiable;
    ``rejected``: those that raised the gap), so the sentence never contradicts the choice."""
    allan = _allan_phrase(sim)
    phrase = _effect_phrase(data, cand, allan, diag)
    if phrase is not None:
        return phrase
    lead = _bandwidth_lead(data, cand, allan) if cand.name == "bandwidth" else allan
    return _random_phrase(lead, diag["correlation"], rows, skip or {}, rejected)


def _effect_phrase(data: GapData, cand: Candidate, allan: str, diag: dict[str, Any]) -> str | None:
    """:func:`where_phrase` for a deterministic effect (and quantization): what its own
    diagnostic shows; None for a random effect."""
    c = diag["correlation"]
    n = cand.name
    if n == "temperature_bias":
        return f"{allan}; residual correlates with temp_c, r = {c.get('temp_c', 0.0):.2f}"
    if n == "warmup_transient":
        wt = cand.fit.model.get("warmup_transient")
        tau = float(wt.tau_s) if isinstance(wt, WarmupTransient) else 0.0
        parts = diag["mean_by_tenth_dps"]
        return (
            f"{allan}; residual vs time: {parts[0]:+.3f} deg/s in the first tenth of the log "
            f"against the mean (decays like exp(-t / {tau:.0f} s))"
        )
    if n == "motion_offset":
        mo = cand.fit.model.get("motion_offset")
        off = float(mo.offset_dps) if isinstance(mo, MotionOffset) else 0.0
        return (
            f"{allan}; residual correlates with moving (against standing), "
            f"r = {c.get('moving', 0.0):.2f}: the bias while moving is {off:+.3f} deg/s off "
            "the bias at rest"
        )
    if n == "scale_factor":
        return f"{allan}; residual correlates with the true rate, r = {c['true_rate']:.2f}"
    if n == "scale_asymmetry":
        sl, sr = diag["slope_left_right"]
        return (
            f"{allan}; residual vs true rate by sign: slope {sl:+.4f} in left turns (+), "
            f"{sr:+.4f} in right turns (-)"
        )
    if n == "time_offset":
        return f"{allan}; residual correlates with the true rate's derivative (lag), r = {c['rate_derivative']:.2f}"
    if n == "saturation":
        h = diag["histogram"]
        return (
            f"{allan}; histogram: {h['samples_at_max']} samples piled at +/-{h['max_abs_omega_dps']:.3f} deg/s "
            f"(clipping rail); residual correlates with the true rate, r = {c['true_rate']:.2f}"
        )
    if n == "quantization":
        h = diag["histogram"]
        return (
            f"histogram: {100.0 * h.get('on_lattice', 0.0):.1f} % of omega values on a lattice of "
            f"{h.get('lattice_dps', 0.0):.6g} deg/s (log resolution {data.resolution_dps:g} deg/s), "
            "the model's output is continuous"
        )
    return None


def _bandwidth_lead(data: GapData, cand: Candidate, allan: str) -> str:
    """The Allan phrase, with what the fitted low-pass does to neighbouring samples."""
    bw = cand.fit.model.get("bandwidth")
    if not isinstance(bw, Bandwidth):
        return allan
    a = pole(bw.section_hz(), 1.0 / data.fs_hz)
    kind = "" if bw.sections == 1 else f"{bw.sections} sections "
    return (
        f"{allan}; neighbouring samples correlate (a low-pass of {kind}at {bw.cutoff_hz:.3g} Hz: "
        f"the white noise is {math.sqrt(white_factor(a, bw.sections)):.3g}x what their "
        "differences alone suggest)"
    )


def _random_phrase(
    lead: str,
    c: dict[str, float],
    rows: Sequence[dict[str, Any]],
    skip: dict[str, str],
    rejected: Sequence[dict[str, Any]],
) -> str:
    """For a random effect: the regressor that correlates most with the residual (``c``: each
    regressor's r) and why its own effect was not chosen."""
    regs = {k: v for k, v in c.items() if k in _EFFECT_OF}
    if not regs:
        return lead
    big = max(regs.items(), key=lambda kv: abs(kv[1]))
    if abs(big[1]) < _STRONG_R:
        return (
            f"{lead}; no measured regressor explains it (largest |r|: {big[0]}, r = {big[1]:.2f})"
        )
    eff = _EFFECT_OF[big[0]]
    why = _why_not(eff, rows, skip, rejected)
    return f"{lead}; {big[0]} correlates with the residual (r = {big[1]:.2f}), but {eff} {why}"
