"""Fitting a gyro error model to a prepared log: the deterministic prediction D, the
likelihood (whitened block residual + lattice), BIC, and the alternating least-squares /
maximum-likelihood fit of every free parameter.

Rates deg/s, + = CCW; times s; temperatures deg C. Effect names and parameters are those of
:mod:`hdrd.sim.gyro`. Pure.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.bounds import DELAY_MAX_S, GAIN_MIN, at_rest, param_bounds
from hdrd.analysis.gap.data import GapData
from hdrd.analysis.gap.lattice import on_lattice
from hdrd.analysis.gap.lowpass import (
    Slow,
    cascade_cutoff_hz,
    differences,
    fit_lowpass,
    pole,
    slow_noise,
)
from hdrd.analysis.gap.noise import Noise, Whitener
from hdrd.analysis.gap.optimize import least_squares_bounded, minimize_simplex
from hdrd.analysis.gap.predict import NOISE_EFFECTS, deterministic_part
from hdrd.analysis.gap.white import white_levels
from hdrd.sim.effects import (
    Bandwidth,
    BiasInstability,
    Quantization,
    RateRandomWalk,
    Saturation,
    TemperatureBias,
    WhiteNoise,
)
from hdrd.sim.gyro import GyroModel

__all__ = [
    "GLITCH_P",
    "NOISE_EFFECTS",
    "Fit",
    "Fitter",
    "clipping_rail",
    "deterministic_part",
    "fit_model",
    "with_params",
]

FloatArray = npt.NDArray[np.float64]

GLITCH_P = 1e-3  # per-sample probability of an off-lattice value under a quantised model


# -- fitting a model -------------------------------------------------------------------------------

# Free deterministic parameters: (effect, parameter) -> (transform, finite-difference step).
# "log": the optimiser works on ln(value) (positive parameters).
_DET_PARAMS: dict[str, tuple[tuple[str, str, float], ...]] = {
    "static_bias": (("bias_dps", "lin", 1e-3),),
    "scale_factor": (("error", "lin", 1e-4),),
    "scale_asymmetry": (("pos_error", "lin", 1e-4), ("neg_error", "lin", 1e-4)),
    "warmup_transient": (("amplitude_dps", "lin", 1e-3), ("tau_s", "log", 1e-3)),
    "temperature_bias": (("coeff_dps_per_c", "lin", 1e-4),),
    "motion_offset": (("offset_dps", "lin", 1e-3),),
    "time_offset": (("delay_s", "lin", 1e-3),),
}

_TAU_BOUNDS = (1.0, 1e6)


@dataclass(frozen=True)
class Fit:
    """A model fitted to the log: its log-likelihood (Gaussian block part + lattice part),
    number of fitted parameters k, BIC = -2 lnL + k ln(n blocks), the deterministic prediction
    D (per sample) and its block means Dbar (used blocks)."""

    model: GyroModel
    lnl: float
    k: int
    bic: float
    d: FloatArray = field(repr=False)
    dbar: FloatArray = field(repr=False)
    noise: Noise = field(repr=False)
    quad: bool = False


def _free_det(model: GyroModel, quad: bool) -> list[tuple[str, str, str, float]]:
    out = []
    for e in model.effects:
        for p, kind, h in _DET_PARAMS.get(e.name, ()):
            out.append((e.name, p, kind, h))
        if e.name == "temperature_bias" and quad:
            out.append((e.name, "quad_dps_per_c2", "lin", 1e-5))
    return out


def with_params(
    model: GyroModel,
    free: list[tuple[str, str, str, float]],
    theta: FloatArray,
    tau_bounds: tuple[float, float] = _TAU_BOUNDS,
) -> GyroModel:
    upd: dict[str, dict[str, float]] = {}
    lo, hi = math.log(tau_bounds[0]), math.log(tau_bounds[1])
    for (eff, p, kind, _), v in zip(free, theta):
        val = float(v)
        if kind == "log":
            val = float(math.exp(min(max(val, lo), hi)))
        if eff == "time_offset":
            val = min(max(val, -DELAY_MAX_S), DELAY_MAX_S)
        if p in ("error", "pos_error", "neg_error"):
            val = max(val, GAIN_MIN)
        upd.setdefault(eff, {})[p] = val
    effects = []
    for e in model.effects:
        if e.name in upd:
            effects.append(replace(e, **upd[e.name]))
        else:
            effects.append(e)
    return GyroModel(tuple(effects))


def _theta(model: GyroModel, free: list[tuple[str, str, str, float]]) -> FloatArray:
    vals = []
    for eff, p, kind, _ in free:
        v = float(getattr(model.get(eff), p))
        vals.append(math.log(v) if kind == "log" else v)
    return np.asarray(vals, dtype=np.float64)


def _noise_of(data: GapData, model: GyroModel, d: FloatArray, extra_var: float) -> Noise:
    q = model.get("quantization")
    bi = model.get("bias_instability")
    rw = model.get("rate_random_walk")
    q_step = float(q.step_dps) if isinstance(q, Quantization) else 0.0
    wv, after = white_levels(data, d, q_step, model) if "white_noise" in model else (1e-10, 0.0)
    return Noise(
        white_var=wv,
        q_step=q_step,
        after_var=after,
        bi_sigma=float(bi.sigma_dps) if isinstance(bi, BiasInstability) else 0.0,
        bi_tau=float(bi.tau_s) if isinstance(bi, BiasInstability) else 300.0,
        rrw_k=float(rw.k_dps_per_sqrt_s) if isinstance(rw, RateRandomWalk) else 0.0,
        extra_var=extra_var,
    )


def _model_noise(model: GyroModel, noise: Noise, fs_hz: float) -> GyroModel:
    """The model with its noise effects' parameters set from ``noise``."""
    out = model
    if "white_noise" in model:
        out = out.with_effect(WhiteNoise(density_dps_per_rthz=math.sqrt(noise.white_var / fs_hz)))
    bw = model.get("bandwidth")
    if isinstance(bw, Bandwidth):
        out = out.with_effect(
            replace(bw, output_noise_dps_per_rthz=math.sqrt(noise.after_var / fs_hz))
        )
    if "bias_instability" in model:
        out = out.with_effect(BiasInstability(sigma_dps=noise.bi_sigma, tau_s=noise.bi_tau))
    if "rate_random_walk" in model:
        out = out.with_effect(RateRandomWalk(k_dps_per_sqrt_s=noise.rrw_k))
    return out


def _lattice_loglik(data: GapData, model: GyroModel) -> float:
    """Log-likelihood gain of the recorded values under the model's ADC lattice against a
    continuous output recorded at the log's resolution: a value on the lattice has probability
    ~ f(x) * step instead of f(x) * resolution; off it only a glitch (:data:`GLITCH_P`)."""
    q = model.get("quantization")
    if not isinstance(q, Quantization):
        return 0.0
    off = data.lattice.offset_dps if data.lattice is not None else 0.0
    on = on_lattice(data.omega[~data.excluded], q.step_dps, off, data.resolution_dps)
    n_on = int(on.sum())
    n_off = int(on.shape[0] - n_on)
    gain = math.log((1.0 - GLITCH_P) * q.step_dps / data.resolution_dps + GLITCH_P)
    return n_on * gain + n_off * math.log(GLITCH_P)


def _count_params(model: GyroModel, free_det: int, data: GapData) -> int:
    k = free_det
    if "bandwidth" in model and at_rest(data):
        k += 2  # the cutoff, and the white level after the low-pass
    for e in model.effects:
        k += {
            "white_noise": 1,
            "bias_instability": 2,
            "rate_random_walk": 1,
            "quantization": 1,
            "saturation": 1,
        }.get(e.name, 0)
    if data.truth_source.startswith("heading_truth"):
        k += 1  # the truth's own noise variance
    return k


class Fitter:
    """Fits the free parameters of one model structure to one log."""

    def __init__(self, data: GapData) -> None:
        self.data = data
        self.ebar = data.block_residual(data.omega)
        self.heading = data.truth_source.startswith("heading_truth")
        self.rest = at_rest(data)
        bounds = param_bounds(data)
        # A warm-up transient must visibly decay within the log; slower it is just a trend.
        self.tau_bounds = bounds[("warmup_transient", "tau_s")][:2]
        self.bi_tau_bounds = bounds[("bias_instability", "tau_s")][:2]

    def dbar(self, model: GyroModel) -> tuple[FloatArray, FloatArray]:
        d = deterministic_part(self.data, model)
        return d, self.data.block_mean(d)

    def det_problem(
        self, model: GyroModel, free: list[tuple[str, str, str, float]], wh: Whitener
    ) -> tuple[Callable[[FloatArray], FloatArray], FloatArray, FloatArray]:
        """The least-squares problem of the ``free`` deterministic parameters: the whitened
        residual as a function of theta (log-transformed where positive), its start and
        finite-difference steps. :func:`with_params` turns theta back into a model."""
        wy = wh.whiten(self.ebar)

        def res(theta: FloatArray) -> FloatArray:
            _, db = self.dbar(with_params(model, free, theta, self.tau_bounds))
            return np.asarray(wy - wh.whiten(db))

        return res, _theta(model, free), np.array([f[3] for f in free])

    def _lsq(
        self, model: GyroModel, free: list[tuple[str, str, str, float]], wh: Whitener
    ) -> GyroModel:
        res, theta0, h = self.det_problem(model, free, wh)
        lo, hi = self.theta_bounds(free)
        theta = least_squares_bounded(res, theta0, h, lo, hi)
        return with_params(model, free, theta, self.tau_bounds)

    def theta_bounds(
        self, free: list[tuple[str, str, str, float]]
    ) -> tuple[FloatArray, FloatArray]:
        """Bounds of the deterministic parameters theta (log of tau), from :func:`param_bounds`."""
        lo = np.full(len(free), -np.inf)
        hi = np.full(len(free), np.inf)
        for i, (eff, p, kind, _) in enumerate(free):
            if kind == "log":
                lo[i], hi[i] = math.log(self.tau_bounds[0]), math.log(self.tau_bounds[1])
            elif eff == "time_offset":
                lo[i], hi[i] = -DELAY_MAX_S, DELAY_MAX_S
            elif p in ("error", "pos_error", "neg_error"):
                lo[i] = GAIN_MIN
        return lo, hi

    def fit_det(self, model: GyroModel, noise: Noise, quad: bool) -> GyroModel:
        """Least squares of the deterministic parameters, noise fixed, weighted by the white
        part of the noise only: deterministic before stochastic, so that a correlated random
        process in the model (bias instability, random walk) cannot take over part of what a
        measured regressor explains. The static bias, which is also where a random walk
        starts at power-on, is then refitted with the full whitening."""
        free = _free_det(model, quad)
        if not free:
            return model
        white = replace(noise, bi_sigma=0.0, rrw_k=0.0)
        model = self._lsq(model, free, Whitener(self.data, white))
        if noise.bi_sigma > 0 or noise.rrw_k > 0:
            bias = [f for f in free if f[0] == "static_bias"]
            if bias:
                model = self._lsq(model, bias, Whitener(self.data, noise))
        return model

    def _slow(self, noise: Noise) -> Slow:
        """The noise's slow processes per sample (the low-pass fit's known part)."""
        return slow_noise(noise.bi_sigma, noise.bi_tau, noise.rrw_k, 1.0 / self.data.fs_hz)

    def _lowpass_input(self, d: FloatArray, noise: Noise) -> tuple[FloatArray, float, Slow]:
        """Neighbouring differences of the unexplained residual, the ADC's white variance
        (deg/s)**2 and the slow processes as the noise has them (their power above the block
        frequency: a bias of tau_c a few blocks long has much of it there)."""
        data = self.data
        de = differences(data.omega - data.truth_filled - d, data.valid, data.time_gap)
        return de, noise.q_step**2 / 12.0, self._slow(noise)

    def fit_bandwidth(self, model: GyroModel, noise: Noise) -> GyroModel:
        """At rest: the low-pass cutoff, and the white level after it, by the Whittle
        likelihood of the differences."""
        d, _ = self.dbar(model)
        de, qv, slow = self._lowpass_input(d, noise)
        lp = fit_lowpass(de, self.data.block_s * self.data.fs_hz, qv, slow)
        out = math.sqrt(lp.after_var / self.data.fs_hz)
        return model.with_effect(
            Bandwidth(
                cutoff_hz=cascade_cutoff_hz(lp.a, lp.order, 1.0 / self.data.fs_hz),
                output_noise_dps_per_rthz=out,
                sections=lp.order,
            )
        )

    def hf_gain(self, model: GyroModel, d: FloatArray, noise: Noise) -> float:
        """At rest, with a low-pass in the model: the log-likelihood its spectrum gains over
        white noise in the neighbouring differences (the frequencies above the blocks');
        0 otherwise (the white model is the reference)."""
        bw = model.get("bandwidth")
        if not (self.rest and isinstance(bw, Bandwidth)):
            return 0.0
        de, qv, slow = self._lowpass_input(d, noise)
        a = pole(bw.section_hz(), 1.0 / self.data.fs_hz)
        return fit_lowpass(de, self.data.block_s * self.data.fs_hz, qv, slow, a, bw.sections).gain

    def loglik(self, model: GyroModel, noise: Noise, dbar: FloatArray) -> float:
        return Whitener(self.data, noise).loglik(self.ebar - dbar) + _lattice_loglik(
            self.data, model
        )

    def noise_problem(
        self, noise: Noise, dbar: FloatArray, which: Sequence[str]
    ) -> tuple[Callable[[FloatArray], float], FloatArray, Callable[[FloatArray], Noise]]:
        """The maximum-likelihood problem of the named noise parameters: the negative
        log-likelihood of x (their logarithms), its start, and x -> Noise (bounds applied)."""
        y = self.ebar - dbar
        lo, hi = self.bi_tau_bounds

        def build(x: FloatArray) -> Noise:
            kw: dict[str, float] = {}
            for name, v in zip(which, x):
                kw[name] = float(math.exp(min(max(v, -40.0), 20.0)))
            if "bi_tau" in kw:
                kw["bi_tau"] = min(max(kw["bi_tau"], lo), hi)
            return replace(noise, **kw)

        def nll(x: FloatArray) -> float:
            return -Whitener(self.data, build(x)).loglik(y)

        x0 = []
        for w in which:
            v = getattr(noise, w)
            x0.append(math.log(v) if v > 0 else math.log(1e-6))
        return nll, np.array(x0), build

    def fit_noise(
        self, model: GyroModel, noise: Noise, dbar: FloatArray, which: Sequence[str]
    ) -> Noise:
        """Maximum likelihood of the named noise parameters (log scale), others fixed."""
        which = [w for w in which if w != "extra_var" or self.heading]
        if not which:
            return noise
        nll, x0, build = self.noise_problem(noise, dbar, which)
        lo = np.full(len(which), -40.0)
        hi = np.full(len(which), 20.0)
        for i, w in enumerate(which):
            if w == "bi_tau":
                lo[i], hi[i] = math.log(self.bi_tau_bounds[0]), math.log(self.bi_tau_bounds[1])
        return build(minimize_simplex(nll, x0, lo, hi))

    def _white(self, model: GyroModel, d: FloatArray, noise: Noise) -> Noise:
        if "white_noise" not in model:
            return noise
        wv, after = white_levels(self.data, d, noise.q_step, model, self._slow(noise))
        return replace(noise, white_var=wv, after_var=after)

    def finish(self, model: GyroModel, noise: Noise, quad: bool) -> Fit:
        d, db = self.dbar(model)
        noise = self._white(model, d, noise)
        full = _model_noise(model, noise, self.data.fs_hz)
        lnl = self.loglik(full, noise, db) + self.hf_gain(full, d, noise)
        k = _count_params(full, len(_free_det(full, quad)), self.data)
        bic = -2.0 * lnl + k * math.log(self.data.n_used)
        return Fit(model=full, lnl=lnl, k=k, bic=bic, d=d, dbar=db, noise=noise, quad=quad)

    def standard_errors(self, fit: Fit) -> dict[str, dict[str, float]]:
        """Standard errors of a fit's deterministic parameters (the static bias left out:
        where a power-on puts it is no property of the unit), by effect and parameter, in
        the parameter's units (deg/s, s, ...): the covariance of :meth:`fit_det`'s estimate,
        linearised at the fit, under the fit's whole noise model. That estimate weighs the
        blocks by the white part of the noise only (deterministic before stochastic); its
        error is A n with A = (J'J)^-1 J' M_w (J the whitened Jacobian, M_w the white
        whitening), n of covariance Sigma = (M'M)^-1 (M the full whitening, correlated noise
        and a heading truth's error included), so Cov = Z'Z with Z = M^-T A'. A parameter
        the data cannot determine (a singular J'J) is left out."""
        free = _free_det(fit.model, fit.quad)
        if not free or not any(p[0] != "static_bias" for p in free):
            return {}
        theta = _theta(fit.model, free)
        cols = []
        for i, (_, _, _, h) in enumerate(free):
            up, dn = theta.copy(), theta.copy()
            up[i] += h
            dn[i] -= h
            _, bu = self.dbar(with_params(fit.model, free, up, self.tau_bounds))
            _, bd = self.dbar(with_params(fit.model, free, dn, self.tau_bounds))
            cols.append((bu - bd) / (2.0 * h))
        jac = np.stack(cols, axis=1)
        eye = np.eye(jac.shape[0])
        m_w = Whitener(self.data, replace(fit.noise, bi_sigma=0.0, rrw_k=0.0)).whiten(eye)
        m_f = Whitener(self.data, fit.noise).whiten(eye)
        jw = m_w @ jac
        info = jw.T @ jw
        if np.linalg.cond(info) > 1e12:
            return {}
        z = np.linalg.solve(m_f.T, np.linalg.solve(info, jw.T @ m_w).T)
        var = np.einsum("ij,ij->j", z, z)
        out: dict[str, dict[str, float]] = {}
        for (eff, p, kind, _), th, v in zip(free, theta, var):
            se = math.sqrt(float(v)) * (math.exp(float(th)) if kind == "log" else 1.0)
            if eff != "static_bias" and math.isfinite(se):
                out.setdefault(eff, {})[p] = se
        return out

    def full(
        self, model: GyroModel, quad: bool = False, extra_var: float = 0.0, rounds: int = 2
    ) -> Fit:
        """Fit every free parameter of the model: alternate deterministic least squares, the
        low-pass (at rest) and maximum likelihood of the noise."""
        d, db = self.dbar(model)
        noise = _noise_of(self.data, model, d, extra_var)
        if self.heading and noise.extra_var == 0.0:
            noise = replace(noise, extra_var=float(np.var(self.ebar - db)))
        which = ["extra_var"] if self.heading else []
        if "bias_instability" in model:
            which += ["bi_sigma", "bi_tau"]
        if "rate_random_walk" in model:
            which += ["rrw_k"]
        for _ in range(rounds):
            model = self.fit_det(model, noise, quad)
            if self.rest and "bandwidth" in model:
                model = self.fit_bandwidth(model, noise)
            d, db = self.dbar(model)
            noise = self._white(model, d, noise)
            noise = self.fit_noise(model, noise, db, which)
            if not which:
                break
        return self.finish(model, noise, quad)


def fit_model(data: GapData, model: GyroModel) -> Fit:
    """Refit all parameters of ``model`` to the log (its structure unchanged)."""
    f = Fitter(data)
    tb = model.get("temperature_bias")
    quad = isinstance(tb, TemperatureBias) and tb.quad_dps_per_c2 != 0.0
    if "saturation" in model and clipping_rail(data) is not None:
        model = model.with_effect(Saturation(limit_dps=clipping_rail(data) or 200.0))
    if "quantization" in model and data.lattice is not None:
        model = model.with_effect(Quantization(step_dps=data.lattice.step_dps))
    return f.full(model, quad=quad)


def clipping_rail(data: GapData) -> float | None:
    """The clipping level the histogram suggests: the largest |omega| (deg/s) of the samples
    that count (not excluded)."""
    m = float(np.max(np.abs(data.omega[~data.excluded]), initial=0.0))
    return m if m > 0 else None
