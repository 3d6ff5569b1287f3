"""The report JSON and the printed summary of a model-gap run (docs/model-gap.md). Pure."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from hdrd.analysis.gap.candidates import ALPHA, BIC_MARGIN
from hdrd.analysis.gap.data import GapData
from hdrd.analysis.gap.dither import DITHERED, fast_noise_sd
from hdrd.analysis.gap.metric import GAP_METRIC
from hdrd.analysis.gap.search import Ambiguity, GapResult, Step, sig4
from hdrd.sim.effects import MotionOffset, Quantization
from hdrd.sim.grades import model_noise
from hdrd.sim.gyro import GyroModel

__all__ = ["PROFILE_ORDER", "gyro_section", "summary", "to_report"]


def to_report(res: GapResult) -> dict[str, Any]:
    """The report JSON (docs/model-gap.md): the required keys first, then the details."""
    d = res.data
    return {
        "initial_model": res.initial_model.names(),
        "steps": [_step_json(s) for s in res.steps],
        "final_model": res.final_model.names(),
        "gap_initial": sig4(res.initial_sim.gap),
        "gap_final": sig4(res.final_sim.gap),
        "gap_metric": GAP_METRIC,
        "gap_as_given": sig4(res.gap_as_given),
        "gap_noise": res.gap_noise,
        "final_at_bound": list(res.final_at_bound),
        "rejected": list(res.rejected),
        "ambiguous": [_ambiguity_json(a) for a in res.ambiguous],
        "revisions": list(res.revisions),
        "not_identifiable": res.not_identifiable,
        "remaining_candidates": list(res.remaining),
        "initial_params": res.initial_fit.model.to_dict()["effects"],
        "final_params": res.final_model.to_dict()["effects"],
        "final_standard_errors": {
            e: {k: sig4(v) for k, v in ps.items()} for e, ps in res.final_standard_errors.items()
        },
        "final_diagnostics": res.final_diagnostics,
        "criterion": (
            f"BIC = -2 lnL + k ln(n) on n = {d.n_used} blocks of {d.block_s:g} s; an effect is "
            f"added if BIC falls by more than {BIC_MARGIN:g} and the likelihood-ratio test gives "
            f"p < {ALPHA:g}"
        ),
        "log": _log_json(d),
    }


def _step_json(s: Step) -> dict[str, Any]:
    return {
        "where": s.where,
        "effect": s.effect,
        "params": s.params,
        "gap_before": sig4(s.gap_before),
        "gap_after": sig4(s.gap_after),
        "gap_over_seeds": None if s.gap_over_seeds is None else [sig4(g) for g in s.gap_over_seeds],
        "delta_bic": round(s.delta_bic, 2),
        "p_value": float(f"{s.p_value:.3g}"),
        "ambiguous_with": list(s.ambiguous_with),
        "at_bound": list(s.at_bound),
        "candidates": list(s.candidates),
        "diagnostics": s.diagnostics,
    }


def _ambiguity_json(a: Ambiguity) -> dict[str, Any]:
    return {
        "step": a.step,
        "effects": list(a.effects),
        "chosen": a.chosen,
        "delta_bic": list(a.delta_bic),
        "contribution_r": list(a.contribution_r),
        "note": a.note,
    }


def _log_json(d: GapData) -> dict[str, Any]:
    return {
        "name": d.name,
        "samples": int(d.t.shape[0]),
        "duration_s": round(d.duration_s, 3),
        "rate_hz": round(d.fs_hz, 4),
        "truth": d.truth_source,
        "block_s": d.block_s,
        "blocks_used": d.n_used,
        "temp_c": d.temp_c is not None,
        "excluded_samples": int(d.excluded.sum()),
        "time_gaps": int(d.time_gap.sum()),
        "standing_samples": int(d.standing.sum()),
        "blocks_at_rest": int(d.brest[d.bvalid].sum()) if d.brest.shape[0] else 0,
    }


def _bound_line(b: dict[str, Any]) -> str:
    return (
        f"  AT BOUND: {b['effect']}.{b['param']} = {b['value']:.4g} is at its {b['bound']} "
        f"bound ({b['range']}): a limit, not an estimate"
    )


def _step_lines(i: int, s: Step, amb: Ambiguity | None, gap_noise: dict[str, Any]) -> list[str]:
    """The summary's lines of step ``i`` (``amb``: its rivals; ``gap_noise``: the final gap's
    seed-to-seed noise, :attr:`GapResult.gap_noise`)."""
    ps = ", ".join(f"{k}={v:.4g}" for k, v in s.params.items())
    lines = [f"step {i}: {s.effect} ({ps})", f"  where: {s.where}"]
    seeds = ""
    if s.gap_over_seeds is not None:
        b, a, sd = s.gap_over_seeds
        seeds = (
            f" (one seed; the mean over {gap_noise['seeds']} seeds {b:.3g} -> {a:.3g}, "
            f"seed-to-seed sd {sd:.2g})"
        )
    lines.append(f"  gap {s.gap_before:.3g} -> {s.gap_after:.3g}{seeds}, dBIC {s.delta_bic:.1f}")
    if amb is not None:
        lines.append(f"  AMBIGUOUS: {amb.note}")
    lines.extend(_bound_line(b) for b in s.at_bound if b["effect"] == s.effect)
    return lines


def _rejected_line(rj: dict[str, Any]) -> str:
    return (
        f"not added at step {rj['step']}: {rj['effect']} (dBIC {rj['delta_bic']:+.1f}): "
        f"the gap rose with it, {rj['gap_before']:.3g} -> {rj['gap_with_it']:.3g}"
        + (
            f" (mean over the seeds {rj['gap_over_seeds'][0]:.3g} -> "
            f"{rj['gap_over_seeds'][1]:.3g}, more than their sd {rj['gap_over_seeds'][2]:.2g})"
            if "gap_over_seeds" in rj
            else ""
        )
    )


def summary(res: GapResult) -> str:
    """A few lines for people: what was found, the gap before and after, its noise."""
    d = res.data
    left = []
    if d.excluded.any():
        left.append(f"{int(d.excluded.sum())} samples excluded")
    if d.time_gap.any():
        left.append(f"{int(d.time_gap.sum())} time gaps")
    lines = [
        (
            f"{d.name or 'log'}: {d.t.shape[0]} samples over {d.duration_s / 60.0:.1f} min, "
            f"truth from {d.truth_source}, {d.n_used} blocks of {d.block_s:g} s"
            + (f" ({', '.join(left)})" if left else "")
        ),
        (
            f"start: {' + '.join(res.initial_model.names()) or '(empty)'}, gap "
            f"{res.initial_sim.gap:.3g} (parameters refitted; {res.gap_as_given:.3g} as given)"
        ),
    ]
    amb = {a.step: a for a in res.ambiguous}
    for i, s in enumerate(res.steps, 1):
        lines.extend(_step_lines(i, s, amb.get(i), res.gap_noise))
    lines.extend(_rejected_line(rj) for rj in res.rejected)
    for rv in res.revisions:
        lines.append(
            f"revised after step {rv['after_step']}: {rv['effect']} {rv['action']} (dBIC {rv['delta_bic']:+.1f})"
        )
    if not res.steps:
        lines.append("no missing effect found: the model explains the log")
    best = next((c for c in res.remaining), None)
    if best is not None:
        lines.append(
            f"nothing else significant (best remaining: {best['effect']}, dBIC {best['delta_bic']:+.1f})"
        )
    gn = res.gap_noise
    lines.append(
        f"final: {' + '.join(res.final_model.names())}, gap {res.final_sim.gap:.3g} "
        f"(seed to seed: sd {gn['gap_final_sd']:.2g}, {gn['gap_final_range'][0]:.3g}-"
        f"{gn['gap_final_range'][1]:.3g} over {gn['seeds']} seeds)"
    )
    lines.extend(_bound_line(b) for b in res.final_at_bound)
    return "\n".join(lines)


PROFILE_ORDER = (
    "motion_offset_dps",
    "motion_offset_sd_dps",
    "bias_instability_dps",
    "bias_tau_s",
    "rrw_dps_per_sqrt_s",
    "white_dps_per_rthz",
    "quant_step_dps",
    "temp_coeff_dps_per_c",
)
"""The keys ``--gyro-out`` writes, in this order (of :data:`hdrd.core.gyronoise.NOISE_KEYS`)."""


def gyro_section(model: GyroModel, drive: str, report: Mapping[str, Any] | None = None) -> str:
    """A fitted model as the unit's profile: a ``gyro:`` section of hdrd.yaml, usable as a whole
    ``--config`` file, holding every parameter the fit named that the profile has a key for
    (:data:`PROFILE_ORDER`; an effect the model lacks is left out, i.e. unknown): the motion
    offset (driving bias minus rest bias, deg/s, signed) with its standard error from the
    report's ``final_standard_errors``, the slow noise, the white noise, the output step and
    the temperature coefficient (its size: the profile's is >= 0). ``report``
    (:func:`to_report`) also gives the sample rate at which a comment says whether the noise
    dithers the ADC at rest."""
    known = model_noise(model, source="config").to_dict()
    if "bias_instability_dps" in known:  # its correlation time; the config takes 1 .. 1e6 s
        known["bias_tau_s"] = min(max(known["bias_tau_s"], 1.0), 1e6)
    else:
        known.pop("bias_tau_s", None)
    mo = model.get("motion_offset")
    notes = []
    if isinstance(mo, MotionOffset):
        known["motion_offset_dps"] = mo.offset_dps
        se = ((report or {}).get("final_standard_errors") or {}).get("motion_offset", {})
        if math.isfinite(se.get("offset_dps", math.nan)):
            known["motion_offset_sd_dps"] = se["offset_dps"]
        if mo.coeff_dps_per_mps:
            notes.append(
                f"# left out: motion_offset's speed term ({mo.coeff_dps_per_mps:.4g} deg/s per "
                "m/s), which the profile has no key for"
            )
    rate = float(((report or {}).get("log") or {}).get("rate_hz", math.nan))
    notes.extend(_dither_note(model, rate))
    lines = [
        f"# HDR+'s error model, fitted by `hdrd gap` to {drive} (docs/hdrplus.md,",
        '# "Configuration"); paste into /etc/hdrd/hdrd.yaml, replacing its gyro: section.',
        *notes,
        "gyro:" if known else "gyro: {}  # the fit named no parameter the profile holds",
    ]
    lines += [f"  {k}: {known[k]:.7g}" for k in PROFILE_ORDER if k in known]
    return "\n".join(lines) + "\n"


def _dither_note(model: GyroModel, rate_hz: float) -> list[str]:
    """A comment on whether the noise at the ADC's input dithers it at rest (docs/model-gap.md,
    "Quantization and dither"): [] without a quantization or a sample rate."""
    q = model.get("quantization")
    if not (isinstance(q, Quantization) and math.isfinite(rate_hz) and rate_hz > 0):
        return []
    s = fast_noise_sd(model, rate_hz) / q.step_dps
    if s >= DITHERED:
        return [
            f"# dithered at rest: its noise is {s:.2f} of a step at the ADC; a stop reads its bias"
        ]
    return [
        f"# UNDITHERED at rest: its noise is {s:.2f} of a step at the ADC (dithered from "
        f"{DITHERED:g}); a stop reads the code nearest its bias, up to half a step off"
    ]
