"""Candidate effects: which the log can inform, how each is fitted on top of the current
model, and its score (BIC change, likelihood-ratio p-value). Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.bounds import DELAY_MAX_S, at_rest
from hdrd.analysis.gap.data import GapData, moving_indicator
from hdrd.analysis.gap.fit import NOISE_EFFECTS, Fit, Fitter, clipping_rail
from hdrd.analysis.gap.lowpass import noise_share, pole
from hdrd.analysis.gap.noise import Whitener, adev_cluster_sizes, allan_deviation_masked
from hdrd.analysis.gap.optimize import chi2_sf
from hdrd.core.allan import gauss_markov_adev
from hdrd.sim.effects import (
    Bandwidth,
    BiasInstability,
    MotionOffset,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleAsymmetry,
    ScaleFactor,
    StaticBias,
    TemperatureBias,
    TimeOffset,
    WarmupTransient,
    WhiteNoise,
)
from hdrd.sim.gyro import GyroModel

__all__ = [
    "ALPHA",
    "BIC_MARGIN",
    "CANDIDATES",
    "DETERMINISTIC",
    "MIN_PHASE_BLOCKS",
    "MIN_TEMP_STD_C",
    "SLOW_NOISE",
    "Candidate",
    "evaluate_candidate",
    "not_identifiable",
    "slow_noise_forms",
]

FloatArray = npt.NDArray[np.float64]

CANDIDATES = (
    "static_bias",
    "white_noise",
    "temperature_bias",
    "warmup_transient",
    "motion_offset",
    "scale_factor",
    "scale_asymmetry",
    "time_offset",
    "saturation",
    "quantization",
    "bandwidth",
    "bias_instability",
    "rate_random_walk",
)
"""Effects the workflow may add, in the order they are tried. ``bandwidth`` only at rest,
where the low-pass shapes the noise (the short-tau Allan deviation, neighbouring samples that
correlate); while driving, at a vehicle's yaw dynamics (< 1 Hz) a first-order low-pass is a
pure lag of 1 / (2 pi f_c) and cannot be told from ``time_offset``."""

DETERMINISTIC = (
    "static_bias",
    "temperature_bias",
    "warmup_transient",
    "motion_offset",
    "scale_factor",
    "scale_asymmetry",
    "time_offset",
    "saturation",
)
"""Candidates read against a measured regressor (temperature, time since power-on, moving or
standing, the true rate and its derivative): preferred over a random process that explains
the same variance."""

SLOW_NOISE = ("bias_instability", "rate_random_walk")
"""Random processes slow enough to take over what a deterministic drift explains."""

BIC_MARGIN = 10.0
"""An effect is added only if BIC falls by more than this ("very strong" evidence, Kass &
Raftery 1995: a likelihood ratio above e**5 ~ 150 after the parameter penalty)."""

ALPHA = 1e-3
"""...and only if the likelihood-ratio test rejects "effect absent" at this level."""
MIN_TEMP_STD_C = 0.3  # below this temp_c carries no usable information on temperature_bias
MIN_AT_RAIL = 3  # samples at the largest |omega| for a clipping rail to be a candidate
MIN_PHASE_BLOCKS = 5
"""Used blocks needed both standing and moving for ``motion_offset`` (the bias while moving
against the bias at rest)."""


@dataclass(frozen=True)
class Candidate:
    name: str
    fit: Fit
    dk: int
    dlnl: float
    dbic: float
    p: float
    contribution: FloatArray | None  # change of the block prediction, deg/s (deterministic)

    @property
    def significant(self) -> bool:
        return self.dbic < -BIC_MARGIN and self.p < ALPHA


def not_identifiable(data: GapData, model: GyroModel) -> dict[str, str]:
    """Candidates the log's columns cannot inform, with the reason."""
    out: dict[str, str] = {}
    truth = data.truth[data.valid]
    moving = float(np.percentile(np.abs(truth), 99)) if truth.shape[0] else 0.0
    why_temp = _temperature_unidentifiable(data)
    if why_temp:
        out["temperature_bias"] = why_temp
    if moving < 1.0:
        why = "the true rate is (near) zero throughout: gain, lag and clipping need turns"
        for c in ("scale_factor", "scale_asymmetry", "time_offset", "saturation"):
            out[c] = why
    rail = clipping_rail(data)
    if rail is not None and "saturation" not in out:
        kept = np.abs(data.omega[~data.excluded])
        at_rail = int(np.sum(kept >= rail - max(data.resolution_dps, 1e-9) * 1.01))
        if at_rail < MIN_AT_RAIL:
            out["saturation"] = (
                f"only {at_rail} sample(s) at the largest |omega| ({rail:g} deg/s): no rail "
                f"piles values up (a clipping rail holds at least {MIN_AT_RAIL})"
            )
    else:
        wb = data.btruth
        if int((wb > 1.0).sum()) < 2 or int((wb < -1.0).sum()) < 2:
            out["scale_asymmetry"] = "the drive turns one way only"
    if not at_rest(data):
        out["bandwidth"] = (
            "the true rate is not zero (or only known at GPS fixes): at a vehicle's yaw "
            "dynamics a low-pass is a lag of 1 / (2 pi f_c), not told from time_offset "
            "(a candidate at rest only)"
        )
    why_motion = _motion_unidentifiable(data)
    if why_motion:
        out["motion_offset"] = why_motion
    if data.lattice is None:
        out["quantization"] = (
            f"no lattice of values coarser than the log's resolution ({data.resolution_dps:g} deg/s)"
        )
    if data.duration_s < 60.0:
        for c in ("warmup_transient", "bias_instability", "rate_random_walk"):
            out[c] = "the log is shorter than 60 s"
    return out


def _temperature_unidentifiable(data: GapData) -> str:
    """Why the log cannot inform temperature_bias ("": it can)."""
    if data.temp_c is None:
        return "no temp_c column"
    tb = data.block_mean(data.temp_c)
    if float(np.std(tb)) < MIN_TEMP_STD_C:
        return f"temp_c varies by only {float(np.std(tb)):.2f} degC (std)"
    return ""


def _motion_unidentifiable(data: GapData) -> str:
    """Why the log cannot tell a bias while moving from the bias at rest ('' if it can)."""
    mv = moving_indicator(data)
    if mv is None:
        return "no speed column: moving and standing cannot be told apart"
    frac = data.block_mean(mv)
    stand, move = int((frac < 0.1).sum()), int((frac > 0.9).sum())
    if min(stand, move) >= MIN_PHASE_BLOCKS:
        return ""
    gps = (
        " (a GPS course is unknown at a stop: only blocks wholly inside stops count there)"
        if data.heading_mode
        else ""
    )
    return (
        f"{stand} block(s) standing and {move} moving have a known true rate{gps}: the bias "
        f"while moving is read against the bias at rest, {MIN_PHASE_BLOCKS} blocks of each needed"
    )


def _adev_excess_init(
    data: GapData, e: FloatArray, white_var: float, kind: str
) -> tuple[float, float]:
    """Start values for a correlated-noise candidate from the Allan variance of e above the
    white floor (its signature): (sigma, tau_c) for bias_instability, (K, 0) for the RRW."""
    ms = adev_cluster_sizes(data, samples=True)
    ms = ms[ms / data.fs_hz >= data.block_s]
    if ms.shape[0] == 0:
        return (1e-3, 10.0 * data.block_s)
    adev = allan_deviation_masked(e, data.valid, data.fs_hz, ms, data.time_gap)
    taus = ms / data.fs_hz
    ok = np.isfinite(adev)
    taus, avar = taus[ok], adev[ok] ** 2
    if taus.shape[0] == 0:
        return (1e-3, 10.0 * data.block_s)
    excess = np.maximum(avar - white_var / data.fs_hz / taus, 0.0)
    w = 1.0 / np.maximum(avar, 1e-30) ** 2
    if kind == "rate_random_walk":
        g = taus / 3.0
        k2 = float(np.sum(w * g * excess) / np.sum(w * g * g))
        return (math.sqrt(max(k2, 1e-14)), 0.0)
    best = (math.inf, 1e-3, 10.0)
    for tc in np.logspace(
        math.log10(2.0 * data.block_s),
        math.log10(max(data.duration_s / 2.0, 4.0 * data.block_s)),
        12,
    ):
        g = gauss_markov_adev(taus, 1.0, float(tc)) ** 2
        s2 = float(np.sum(w * g * excess) / np.sum(w * g * g))
        sse = float(np.sum(w * (excess - s2 * g) ** 2))
        if sse < best[0]:
            best = (sse, math.sqrt(max(s2, 1e-14)), float(tc))
    return best[1], best[2]


def _candidate_fits(f: Fitter, cur: Fit, name: str) -> list[Fit]:
    """Fitted models of the current model plus effect ``name`` (one per variant)."""
    if name == "bandwidth":  # the cutoff is fitted by Fitter.full (at rest)
        m = cur.model.with_effect(Bandwidth(cutoff_hz=0.25 * f.data.fs_hz))
        fit = f.full(m, quad=cur.quad, extra_var=cur.noise.extra_var)
        return [fit if _passes_noise(fit, f.data.fs_hz) else cur]
    if name in NOISE_EFFECTS:
        return _noise_fits(f, cur, name)
    fits: list[Fit] = []
    for m, quad in _variants(f, cur, name):
        m = f.fit_det(m, cur.noise, quad)
        fits.append(f.finish(m, cur.noise, quad))
    return fits


MIN_LOWPASS_SHARE = 0.05
"""A low-pass through which less than this share of the fast noise passes (the rest is white
noise after it) is no low-pass: its output noise is the white noise already in the model, and
its shape only follows small departures from whiteness (an ADC's; an IMU at 10 Hz got two
sections at 0.004 Hz carrying nothing)."""


def _passes_noise(fit: Fit, fs_hz: float) -> bool:
    """Whether the fitted low-pass carries at least :data:`MIN_LOWPASS_SHARE` of the noise
    after it (per-sample variances)."""
    bw = fit.model.get("bandwidth")
    if not isinstance(bw, Bandwidth):
        return False
    a = pole(bw.section_hz(), 1.0 / fs_hz)
    passed = fit.noise.white_var * noise_share(a, bw.sections)
    return passed >= MIN_LOWPASS_SHARE * (passed + fit.noise.after_var)


def _noise_fits(f: Fitter, cur: Fit, name: str) -> list[Fit]:
    """:func:`_candidate_fits` for a noise effect."""
    data = f.data
    model = cur.model
    noise = cur.noise
    e = data.omega - data.truth_filled - cur.d
    if name == "white_noise":
        m = model.with_effect(WhiteNoise(density_dps_per_rthz=0.05))
        return [f.full(m, quad=cur.quad, extra_var=noise.extra_var, rounds=1)]
    if name == "quantization":
        assert data.lattice is not None
        m = model.with_effect(Quantization(step_dps=data.lattice.step_dps))
        nz = replace(noise, q_step=data.lattice.step_dps)
        return [f.finish(m, nz, cur.quad)]
    if name == "bias_instability":
        s0, tc0 = _adev_excess_init(data, e, noise.white_var, name)
        nz = f.fit_noise(
            model, replace(noise, bi_sigma=s0, bi_tau=tc0), cur.dbar, ["bi_sigma", "bi_tau"]
        )
        m = model.with_effect(BiasInstability(sigma_dps=nz.bi_sigma, tau_s=nz.bi_tau))
    else:
        k0, _ = _adev_excess_init(data, e, noise.white_var, name)
        nz = f.fit_noise(model, replace(noise, rrw_k=k0), cur.dbar, ["rrw_k"])
        m = model.with_effect(RateRandomWalk(k_dps_per_sqrt_s=nz.rrw_k))
    m = f.fit_det(m, nz, cur.quad)
    first = f.finish(m, nz, cur.quad)
    if any(s in model for s in SLOW_NOISE) or ("bandwidth" in model and f.rest):
        # Another slow process is in already: refit them all jointly (a random walk that
        # took over a Gauss-Markov bias's block-to-block changes gives some back). A
        # low-pass fitted at rest without this process took its power above the block
        # frequency (a lower cutoff, more white noise): refit it and the white level too.
        return [first, f.full(first.model, quad=cur.quad, extra_var=nz.extra_var)]
    return [first]


def _variants(f: Fitter, cur: Fit, name: str) -> list[tuple[GyroModel, bool]]:
    """The starting models (with whether the fit has a quadratic term) of a deterministic
    effect added to the current model."""
    data = f.data
    model = cur.model
    e_bar = f.ebar - cur.dbar
    wh = Whitener(data, cur.noise)
    if name == "static_bias":
        return [(model.with_effect(StaticBias(bias_dps=float(np.mean(e_bar)))), cur.quad)]
    if name == "motion_offset":
        return [(model.with_effect(MotionOffset(offset_dps=0.0)), cur.quad)]
    if name == "scale_factor":
        return [(model.with_effect(ScaleFactor(error=0.0)), cur.quad)]
    if name == "scale_asymmetry":
        return [(model.with_effect(ScaleAsymmetry(pos_error=0.0, neg_error=0.0)), cur.quad)]
    if name == "temperature_bias":
        ref = _temperature_ref(data)
        tb = TemperatureBias(coeff_dps_per_c=0.0, ref_temp_c=ref, quad_dps_per_c2=0.0)
        return [
            (model.with_effect(tb), False),
            (model.with_effect(replace(tb, quad_dps_per_c2=1e-6)), True),
        ]
    if name == "saturation":
        return [(model.with_effect(Saturation(limit_dps=clipping_rail(data) or 200.0)), cur.quad)]
    if name == "time_offset":
        # Start from the linear lag regression: e ~ -delay * d(truth)/dt.
        der = data.block_mean(np.gradient(data.truth_filled, data.t))
        wx, wy = wh.whiten(-der), wh.whiten(e_bar)
        d0 = float(np.dot(wx, wy) / max(np.dot(wx, wx), 1e-30))
        d0 = min(max(d0, -DELAY_MAX_S), DELAY_MAX_S)
        return [(model.with_effect(TimeOffset(delay_s=d0)), cur.quad)]
    if name == "warmup_transient":
        amplitude, tau = _warmup_init(f, wh, e_bar)
        return [(model.with_effect(WarmupTransient(amplitude_dps=amplitude, tau_s=tau)), cur.quad)]
    # CANDIDATES and this function are kept in step.
    raise ValueError(f"no fitting rule for {name}")  # pragma: no cover


def _temperature_ref(data: GapData) -> float:
    """The temperature bias's reference, deg C: where the curve's slope equals the straight
    line's least-squares slope over the log. For c (T - r) + q (T - r)**2 that line's slope
    is c + q (2 (m - r) + mu3 / var), m, var, mu3 the temperatures' mean, variance and third
    central moment, so r = m + mu3 / (2 var). coeff is then what a user fitting a line to
    rate against temperature gets, whatever a (possibly spurious) quadratic term does;
    without skew r is the mean temperature."""
    assert data.temp_c is not None
    tv = data.temp_c[data.valid]
    tmean, tvar = float(np.mean(tv)), float(np.var(tv))
    mu3 = float(np.mean((tv - tmean) ** 3))
    return round(tmean + (mu3 / (2.0 * tvar) if tvar > 0 else 0.0), 1)


def _warmup_init(f: Fitter, wh: Whitener, e_bar: FloatArray) -> tuple[float, float]:
    """A warm-up transient's start (amplitude deg/s, tau s): a grid over tau with the
    amplitude (and a constant) by whitened least squares."""
    data = f.data
    wy = wh.whiten(e_bar)
    one = wh.whiten(np.ones_like(e_bar))
    best = (math.inf, 0.0, 60.0)
    lo, hi = f.tau_bounds
    for tau in np.logspace(math.log10(lo), math.log10(hi), 16):
        x = wh.whiten(data.block_mean(np.exp(-data.t / tau)))
        a = np.vstack([x, one]).T
        coef, *_ = np.linalg.lstsq(a, wy, rcond=None)
        sse = float(np.sum((wy - a @ coef) ** 2))
        if sse < best[0]:
            best = (sse, float(coef[0]), float(tau))
    return best[1], best[2]


def evaluate_candidate(f: Fitter, cur: Fit, name: str) -> Candidate:
    fits = _candidate_fits(f, cur, name)
    best = min(fits, key=lambda x: x.bic)
    dk = best.k - cur.k
    dlnl = best.lnl - cur.lnl
    dbic = best.bic - cur.bic
    p = chi2_sf(2.0 * dlnl, max(dk, 1)) if dlnl > 0 else 1.0
    contrib = best.dbar - cur.dbar if name in DETERMINISTIC else None
    return Candidate(name=name, fit=best, dk=dk, dlnl=dlnl, dbic=dbic, p=p, contribution=contrib)


def slow_noise_forms(f: Fitter, cur: Fit) -> list[Fit]:
    """The current model with its slow noise in each form (random walk, bias instability,
    both), every parameter jointly refitted: the likelihood of block means often cannot tell
    them apart on a log a few correlation times long, the Allan deviation over all tau can."""
    base = cur.model.without("bias_instability").without("rate_random_walk")
    bf = f.full(base, quad=cur.quad, extra_var=cur.noise.extra_var)
    rw = min(_candidate_fits(f, bf, "rate_random_walk"), key=lambda x: x.bic)
    bi = min(_candidate_fits(f, bf, "bias_instability"), key=lambda x: x.bic)
    # Both, from either single form (a random walk that took everything leaves the added
    # Gauss-Markov bias no start, and the other way round).
    both = min(
        _candidate_fits(f, rw, "bias_instability") + _candidate_fits(f, bi, "rate_random_walk"),
        key=lambda x: x.bic,
    )
    return [rw, bi, both]
