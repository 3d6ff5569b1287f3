"""The sample-level side of the noise: a sensor low-pass (bandwidth) seen in the differences of
neighbouring samples at rest, which block means cannot see, fitted by the Whittle likelihood of
their spectrum (one or two equal sections, a white level after them; the slow processes' part
known from the block fit: :class:`Slow`). The spectrum and the fit: docs/model-gap.md, section
3. Through the low-pass, neighbouring differences understate the white noise by
(1 - a)**2 / (1 + a) (:func:`white_factor`). Rates deg/s, variances per sample. Pure.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
import numpy.typing as npt

__all__ = [
    "A_MAX",
    "A_MIN",
    "ORDERS",
    "LowpassFit",
    "Slow",
    "cascade_cutoff_hz",
    "cutoff_hz",
    "fit_lowpass",
    "noise_share",
    "pole",
    "slow_noise",
    "white_factor",
]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

A_MIN = 1e-3
"""Smallest pole fitted: a cutoff above ~1.1 x the sample rate is no low-pass in the data."""
A_MAX = 0.999
"""Largest pole: a cutoff of 1.6e-4 x the sample rate (a 1000-sample time constant)."""
_BINS = 4000


def pole(cutoff_hz_: float, dt_s: float) -> float:
    """The low-pass pole a = exp(-2 pi f_c dt) per sample."""
    return math.exp(-2.0 * math.pi * cutoff_hz_ * dt_s)


def cutoff_hz(a: float, dt_s: float) -> float:
    """The cutoff (Hz, -3 dB) of the pole a at the sample period dt_s."""
    return -math.log(a) / (2.0 * math.pi * dt_s)


ORDERS = (1, 2)
"""Equal first-order sections of the low-pass tried (the simulator's ``bandwidth`` with that
many ``sections``): the differences' spectrum of two peaks at the cutoff and falls beyond it,
which one section cannot draw (fitted with one, a phone's filter of two sections at 0.2 Hz
ran the pole to its bound and the white noise to 4x at 50 Hz, 40x at 10 Hz)."""


def noise_share(a: float, order: int) -> float:
    """Variance of white noise after ``order`` equal sections of pole a, per unit variance
    before: (1 - a) / (1 + a) for one, (1 - a)**4 (1 + a**2) / (1 - a**2)**3 for two, summed
    over the impulse response beyond."""
    if order == 1:
        return (1.0 - a) / (1.0 + a)
    if order == 2:
        return (1.0 - a) ** 4 * (1.0 + a * a) / (1.0 - a * a) ** 3
    return float(np.sum(_impulse(a, order) ** 2))


def _impulse(a: float, order: int) -> FloatArray:
    """Impulse response of ``order`` equal sections of pole a, until it has decayed."""
    n = int(min(60.0 * order / max(1.0 - a, 1e-6), 2e6)) + 2
    h = (1.0 - a) * a ** np.arange(n, dtype=np.float64)
    out = h
    for _ in range(order - 1):
        out = np.convolve(out, h)[:n]
    return np.asarray(out)


def cascade_cutoff_hz(a: float, order: int, dt_s: float) -> float:
    """The -3 dB cutoff (Hz) of ``order`` equal sections of pole a at the sample period dt_s
    (as the simulator's ``bandwidth`` with that many ``sections`` reads its cutoff)."""
    return cutoff_hz(a, dt_s) * math.sqrt(2.0 ** (1.0 / order) - 1.0)


def white_factor(a: float, order: int = 1) -> float:
    """Input white variance over the white-equivalent variance of neighbouring differences
    (half their variance), ``order`` sections of pole a."""
    if order == 1:
        return (1.0 + a) / (1.0 - a) ** 2
    return 2.0 / float(np.sum(np.diff(_impulse(a, order), prepend=0.0) ** 2))


def differences(e: FloatArray, valid: BoolArray, time_gap: BoolArray) -> FloatArray:
    """Differences of neighbouring samples, both valid and with no time gap between them."""
    ok = valid[1:] & valid[:-1] & ~time_gap[1:]
    return np.asarray(np.diff(e)[ok])


@dataclass(frozen=True)
class Slow:
    """The slow processes before the low-pass, per sample: a Gauss-Markov bias of variance
    ``gm_var`` (deg/s)**2 and pole ``gm_pole`` = exp(-dt / tau_c), a random walk whose steps
    have variance ``rw_var`` = K**2 dt (deg/s)**2."""

    gm_var: float = 0.0
    gm_pole: float = 0.0
    rw_var: float = 0.0


def slow_noise(sigma_dps: float, tau_s: float, k_dps_per_sqrt_s: float, dt_s: float) -> Slow:
    """:class:`Slow` of a Gauss-Markov bias (sigma deg/s, tau_c s; sigma 0: none) and a random
    walk (K deg/s/sqrt(s)) sampled every ``dt_s``."""
    return Slow(
        gm_var=sigma_dps**2 if sigma_dps > 0.0 else 0.0,
        gm_pole=math.exp(-dt_s / tau_s) if sigma_dps > 0.0 and tau_s > 0.0 else 0.0,
        rw_var=k_dps_per_sqrt_s**2 * dt_s,
    )


@dataclass(frozen=True)
class LowpassFit:
    """Whittle fit of the differences: pole a (0 = no low-pass), input white variance W
    (deg/s)**2 per sample, its log-likelihood, and that of the best white model (a = 0);
    ``after_var``: the white variance per sample after the low-pass beyond the ADC's
    q**2/12, (deg/s)**2 (the output stage's own noise: ``bandwidth``'s output noise)."""

    a: float
    white_var: float
    loglik: float
    loglik_white: float
    after_var: float = 0.0
    order: int = 1
    """Equal first-order sections of the low-pass (:data:`ORDERS`), each of pole ``a``."""

    @property
    def gain(self) -> float:
        """Log-likelihood gained by the low-pass over white noise alone."""
        return self.loglik - self.loglik_white


class _Spectrum:
    """The binned periodogram of the differences and the Whittle likelihood of a model."""

    def __init__(self, de: FloatArray, w_min: float) -> None:
        n = de.shape[0]
        x = de - de.mean()
        per = np.abs(np.fft.rfft(x)) ** 2 / n
        k = np.arange(per.shape[0])
        keep = (k > 0) & (k < n / 2.0) & (2.0 * math.pi * k / n >= w_min)
        w = 2.0 * math.pi * k[keep] / n
        per = per[keep]
        nb = min(_BINS, w.shape[0])
        edges = np.linspace(0, w.shape[0], nb + 1).astype(np.int64)
        self.m = np.diff(edges).astype(np.float64)
        self.i = np.add.reduceat(per, edges[:-1]) / self.m
        self.w = np.add.reduceat(w, edges[:-1]) / self.m
        self.d2 = 2.0 - 2.0 * np.cos(self.w)

    def gain(self, a: float, order: int = 1) -> FloatArray:
        """|H(w)|**2 of ``order`` equal first-order sections of pole a."""
        return np.asarray(((1.0 - a) ** 2 / (1.0 - 2.0 * a * np.cos(self.w) + a * a)) ** order)

    def shape(self, a: float, order: int = 1) -> FloatArray:
        """Spectrum of the differences per unit input white variance, ``order`` poles a."""
        return np.asarray(self.d2 * self.gain(a, order))

    def slow(self, a: float, order: int, slow: Slow | None) -> FloatArray:
        """Spectrum of the differences of the slow processes seen through ``order`` poles a."""
        if slow is None or (slow.gm_var <= 0.0 and slow.rw_var <= 0.0):
            return np.zeros_like(self.w)
        p = slow.gm_pole
        g = slow.gm_var * (1.0 - p * p) / (1.0 - 2.0 * p * np.cos(self.w) + p * p)
        return np.asarray(self.gain(a, order) * (self.d2 * g + slow.rw_var))

    def loglik(self, s: FloatArray) -> float:
        return -float(np.sum(self.m * (np.log(s) + self.i / s)))

    def best_linear(self, gs: list[FloatArray], g0: FloatArray) -> tuple[FloatArray, float]:
        """(c, ln L) maximising the likelihood of S = sum_j c_j gs[j] + g0 over c >= 0, by
        coordinate ascent: one coefficient at a time by Fisher scoring (the spectrum is linear
        in it), clipped at zero, until a sweep gains less than 1e-4."""
        mtot = float(np.sum(self.m))
        c = [
            max(float(np.sum(self.m * np.maximum(self.i - g0, 0.0) / gj)) / mtot, 1e-30)
            for gj in gs
        ]
        c = [x / len(gs) for x in c]
        sp = sum(cj * gj for cj, gj in zip(c, gs)) + g0
        ll = self.loglik(sp)
        for _ in range(60):
            start = ll
            for j, gj in enumerate(gs):
                for _ in range(8):
                    r = self.m / (sp * sp)
                    score = float(np.sum(gj * r * (self.i - sp)))
                    info = float(np.sum(gj * gj * r))
                    new = max(c[j] + score / info, 0.0)
                    while True:  # halve the step until the likelihood does not fall
                        sp_new = sp + (new - c[j]) * gj
                        ll_new = self.loglik(sp_new) if np.all(sp_new > 0) else -math.inf
                        if ll_new >= ll or abs(new - c[j]) <= 1e-12 * max(c[j], 1e-30):
                            break
                        new = 0.5 * (new + c[j])
                    if ll_new < ll:
                        break
                    moved = ll_new - ll
                    c[j], sp, ll = new, sp_new, ll_new
                    if moved < 1e-6:
                        break
            if ll - start < 1e-4:
                break
        return np.asarray(c), ll


def fit_lowpass(
    de: FloatArray,
    block_samples: float,
    q_var: float = 0.0,
    slow: Slow | None = None,
    a: float | None = None,
    order: int = 1,
) -> LowpassFit:
    """Whittle fit of the differences ``de`` (deg/s) from the block frequency (one cycle per
    ``block_samples``) up: the pole a of each section and their number (given, or fitted: a
    over [A_MIN, A_MAX] for each of :data:`ORDERS`, the likelier kept), the input white
    variance W and the white variance after the low-pass (at least the ADC's ``q_var`` =
    q**2/12), with the slow processes (``slow``) known."""
    sp = _spectrum(np.asarray(de, dtype=np.float64), 2.0 * math.pi / max(block_samples, 2.0))
    if not float(np.sum(sp.m)) > 0:  # no frequency above the block's: nothing to fit a pole to
        white = max(float(np.var(de)) / 2.0 - q_var, 0.0) if len(de) else 0.0
        return LowpassFit(
            a=A_MIN if a is None else a,
            white_var=white,
            loglik=0.0,
            loglik_white=0.0,
            order=1 if a is None else order,
        )
    g0 = sp.d2 * q_var
    _, ll_white = sp.best_linear([sp.d2], g0)  # the reference: white noise alone

    def at(av: float, o: int) -> tuple[float, float, float]:
        c, ll = sp.best_linear([sp.shape(av, o), sp.d2], g0 + sp.slow(av, o, slow))
        return float(c[0]), ll, float(c[1])

    if a is None:
        fits = [(*_best_pole(partial(_ll_of, at, o), A_MIN, A_MAX), o) for o in ORDERS]
        a, _, order = max(fits, key=lambda f: f[1])
    a = min(max(a, A_MIN), A_MAX)
    w, ll, after = at(a, order)
    return LowpassFit(
        a=a, white_var=w, loglik=ll, loglik_white=ll_white, after_var=after, order=order
    )


def _ll_of(at: Callable[[float, int], tuple[float, float, float]], order: int, a: float) -> float:
    return at(a, order)[1]


def _best_pole(f: Callable[[float], float], a_lo: float, a_hi: float) -> tuple[float, float]:
    """(a, f(a)) maximising ``f`` over poles in [a_lo, a_hi]: a grid over ln(1 - a), then
    golden-section refinement around the best point."""
    grid = 1.0 - np.logspace(math.log10(1.0 - a_hi), math.log10(1.0 - a_lo), 40)
    vals = [f(float(x)) for x in grid]
    j = int(np.argmax(vals))
    lo = math.log(1.0 - float(grid[min(j + 1, 39)]))
    hi = math.log(1.0 - float(grid[max(j - 1, 0)]))
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = f(1.0 - math.exp(x1)), f(1.0 - math.exp(x2))
    for _ in range(25):
        if f1 > f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = f(1.0 - math.exp(x1))
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = f(1.0 - math.exp(x2))
    a = 1.0 - math.exp(0.5 * (lo + hi))
    fa = f(a)
    return (a, fa) if fa >= vals[j] else (float(grid[j]), vals[j])


_CACHE: dict[tuple[int, float, bytes], _Spectrum] = {}


def _spectrum(de: FloatArray, w_min: float) -> _Spectrum:
    """The binned periodogram of ``de``, remembered for the last few series (a fit asks for
    the same residual's spectrum many times)."""
    key = (de.shape[0], w_min, hashlib.blake2b(de.tobytes(), digest_size=16).digest())
    sp = _CACHE.get(key)
    if sp is None:
        if len(_CACHE) >= 8:
            _CACHE.pop(next(iter(_CACHE)))
        sp = _CACHE[key] = _Spectrum(de, w_min)
    return sp
