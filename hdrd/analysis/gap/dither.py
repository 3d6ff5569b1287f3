"""A quantizer and the noise that dithers it (docs/model-gap.md, "Quantization and dither").

An ADC rounds what reaches it, signal and noise, to a multiple of its step q (zero on a code,
as the simulator's ``quantization``). With noise of sd at least ~0.7 q at its input the
rounding error is white, of variance q**2/12, and the output's mean is the input's; with less
the error follows the signal: a gyro at rest whose noise never crosses a code reads one code,
whatever its bias within that code. Driving's vibration and the car's own sway dither the
same ADC. So where the true rate is known at every sample the model's prediction is the
quantized output's *mean* over the fast noise, not the input (:func:`expected_output`), and
the noise at rest is read from how often the output leaves its code (:func:`dither_sd`), not
from the differences of the codes, which say little once the noise is below a step.

Rates deg/s; sd per sample, deg/s. Pure (scipy.special for the normal distribution).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.lowpass import noise_share
from hdrd.sim.effects import Bandwidth, WhiteNoise
from hdrd.sim.gyro import GyroModel

__all__ = ["DITHERED", "MIN_REST_SAMPLES", "dither_sd", "expected_output", "fast_noise_sd"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

DITHERED = 0.7
"""Noise sd (in steps) from which a quantizer is dithered: the mean of its output is the mean
of its input to exp(-2 pi**2 0.7**2) ~ 6e-5 of a step, its error white of variance q**2/12."""
MIN_REST_SAMPLES = 30
"""Samples at rest needed to read the noise from how often the output leaves its code."""


def _ndtr(x: FloatArray) -> FloatArray:
    from scipy.special import ndtr  # the gap extra; imported when a quantizer is fitted

    return np.asarray(ndtr(x), dtype=np.float64)


def fast_noise_sd(model: GyroModel, fs_hz: float) -> float:
    """The sd per sample (deg/s) of the model's noise that changes from one sample to the
    next at its ADC's input: its white noise (through the low-pass, if any) and the output
    stage's noise after it. The slow processes (bias instability, random walk) hold still
    over a sample: they move the signal, they do not dither it."""
    white = model.get("white_noise")
    var = float(white.density_dps_per_rthz) ** 2 * fs_hz if isinstance(white, WhiteNoise) else 0.0
    bw = model.get("bandwidth")
    if isinstance(bw, Bandwidth):
        a = math.exp(-2.0 * math.pi * bw.section_hz() / fs_hz)
        var = var * noise_share(a, bw.sections) + bw.output_noise_dps_per_rthz**2 * fs_hz
    return math.sqrt(var)


def expected_output(x: npt.ArrayLike, sd: float, step: float) -> tuple[FloatArray, FloatArray]:
    """Mean and variance (deg/s, (deg/s)**2) of round((x + n) / step) * step for Gaussian n of
    sd ``sd`` (deg/s) at each input x (deg/s): the quantized output's mean is x once the
    noise dithers the quantizer (sd >= :data:`DITHERED` steps), the code x sits on without
    noise, a smoothed staircase between."""
    xv = np.asarray(x, dtype=np.float64)
    s = sd / step
    if s >= DITHERED:
        return xv.copy(), np.full(xv.shape, sd * sd + step * step / 12.0)
    u = xv / step
    c0 = np.round(u)
    if s < 1e-9:
        return c0 * step, np.zeros(xv.shape)
    k = math.ceil(6.0 * s) + 1
    mean = np.zeros(xv.shape)
    sq = np.zeros(xv.shape)
    upper = _ndtr((c0 - k - 0.5 - u) / s)
    for j in range(-k, k + 1):
        lower, upper = upper, _ndtr((c0 + j + 0.5 - u) / s)
        p = upper - lower
        mean += p * (c0 + j)
        sq += p * (c0 + j) ** 2
    return mean * step, np.maximum(sq - mean * mean, 0.0) * step * step


_FRAC_BINS = 64


def _golden(f: Any, lo: FloatArray, hi: FloatArray, iters: int) -> FloatArray:
    """Element-wise golden-section maximisation of a vectorised unimodal ``f`` on [lo, hi]."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(iters):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        left = f(x1) > f(x2)  # the maximum is in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
    return np.asarray(0.5 * (lo + hi))


def _counts(codes: IntArray, u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The values' codes relative to the code nearest their input's mean ``u`` (steps), -R..R
    (further ones lumped into the outermost), counted per bin of the mean's position within
    its code (u - round(u), in -1/2..1/2): (counts of shape (bins, 2R + 1), the bins' centres)."""
    r = 4
    near = np.round(u)
    rel = np.clip(codes - near.astype(np.int64), -r, r) + r
    frac = u - near
    b = np.clip(((frac + 0.5) * _FRAC_BINS).astype(np.int64), 0, _FRAC_BINS - 1)
    counts = np.zeros((_FRAC_BINS, 2 * r + 1))
    np.add.at(counts, (b, rel), 1.0)
    centres = (np.arange(_FRAC_BINS) + 0.5) / _FRAC_BINS - 0.5
    return counts, centres


def _loglik(counts: FloatArray, centres: FloatArray, s: float) -> float:
    """Log-likelihood of the counted codes for a noise sd ``s`` (steps): a value whose input
    mean sits at ``centres`` of its code falls on code j with probability
    Phi((j + 1/2 - centre) / s) - Phi((j - 1/2 - centre) / s); the outermost take the tails."""
    r = (counts.shape[1] - 1) // 2
    edges = np.arange(-r, r + 2) - 0.5
    cdf = _ndtr((edges[None, :] - centres[:, None]) / s)
    cdf[:, 0], cdf[:, -1] = 0.0, 1.0
    p = np.maximum(np.diff(cdf, axis=1), 1e-300)
    return float(np.sum(counts * np.log(p)))


def dither_sd(values: npt.ArrayLike, mean: npt.ArrayLike, step: float) -> float | None:
    """The sd (deg/s) of the Gaussian noise at a quantizer's input by maximum likelihood from
    its output ``values`` (deg/s, on multiples of ``step``) and the input's mean at each
    (``mean``, deg/s: the model's prediction): how often and how far the output leaves the
    code its input sits on reads a noise below a step, which the codes' own differences do
    not (a noise of 0.1 step leaves a code in the middle 1 sample in 10**6). None with fewer
    than :data:`MIN_REST_SAMPLES` values. Between 0.005 and 3 steps (a noise that never
    leaves its code: the lower bound). A slow drift the mean does not have reads as noise."""
    v = np.asarray(values, dtype=np.float64)
    if v.shape[0] < MIN_REST_SAMPLES:
        return None
    counts, centres = _counts(np.round(v / step).astype(np.int64), np.asarray(mean) / step)

    def f(log_s: FloatArray) -> FloatArray:
        return np.array([_loglik(counts, centres, math.exp(x)) for x in log_s.tolist()])

    grid = np.linspace(math.log(0.005), math.log(3.0), 12)
    j = int(np.argmax(f(grid)))
    lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, grid.shape[0] - 1)]
    best = _golden(f, np.array([lo]), np.array([hi]), 20)
    return float(math.exp(float(best[0]))) * step
