"""The white noise's level in a prepared log: per sample at the sensor's input, and after its
low-pass (docs/model-gap.md, section 4, "White noise"). Pure.

From the neighbouring differences of the unexplained residual (robust: MAD), less the ADC's
q**2/12; with a GPS-course truth inside the stops (the true rate is zero there), else from
second differences on straight stretches. Where the values sit on an ADC lattice coarse
against the noise the differences take a few discrete values and say little: with a
quantization in the model the level comes from how often the output leaves the code its
input sits on (:func:`.dither.dither_sd`), else from the differences' variance. With a
low-pass at rest the level at its input and the white level after it come from the Whittle
fit of the differences' spectrum (:mod:`.lowpass`).

Rates deg/s, variances (deg/s)**2 per sample.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.bounds import at_rest
from hdrd.analysis.gap.data import GapData, stop_interior
from hdrd.analysis.gap.dither import dither_sd
from hdrd.analysis.gap.lowpass import (
    Slow,
    fit_lowpass,
    noise_share,
    pole,
    slow_noise,
    white_factor,
)
from hdrd.analysis.gap.predict import signal
from hdrd.sim.effects import Bandwidth, BiasInstability, RateRandomWalk
from hdrd.sim.gyro import GyroModel

__all__ = ["MIN_STOP_PAIRS", "STRAIGHT_DPS", "white_levels"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

STRAIGHT_DPS = 1.0
"""With a GPS-course truth the white noise is read where the car drives straight (true rate
below this, deg/s): between fixes the true rate is unknown, and in turns its own changes
from one sample to the next would pass for noise."""

MIN_STOP_PAIRS = 30
"""Neighbouring sample pairs inside stops needed to read the white noise there."""

_TINY = 1e-12


def white_levels(
    data: GapData, d: FloatArray, q_step: float, model: GyroModel, slow: Slow | None = None
) -> tuple[float, float]:
    """(W, after): the white-noise variance per sample at the sensor's input, and the white
    variance per sample after its low-pass beyond the ADC's q**2/12 (the model's
    ``bandwidth`` output noise: fitted at rest, else as the model gives it), (deg/s)**2.
    ``d``: the model's deterministic prediction D per sample; ``slow``: the slow processes
    (default: the model's)."""
    bw = model.get("bandwidth")
    after = bw.output_noise_dps_per_rthz**2 * data.fs_hz if isinstance(bw, Bandwidth) else 0.0
    if data.heading_mode:
        return _heading(data, d, q_step, model, after), after
    e = data.omega - data.truth_filled - d
    ok = data.valid[1:] & data.valid[:-1] & ~data.time_gap[1:]
    de = np.diff(e)[ok]
    if de.shape[0] < 10:
        return float(np.var(e[data.valid])), after
    if isinstance(bw, Bandwidth) and at_rest(data):
        a = pole(bw.section_hz(), 1.0 / data.fs_hz)
        slow = slow or _slow(model, data)
        fit = fit_lowpass(de, data.block_s * data.fs_hz, q_step**2 / 12.0, slow, a, bw.sections)
        return float(max(fit.white_var, _TINY)), fit.after_var
    return _from_differences(data, de, q_step, model, data.sample_truth, after), after


def _slow(model: GyroModel, data: GapData) -> Slow:
    """The model's slow processes, per sample (the low-pass fit's known part)."""
    bi, rw = model.get("bias_instability"), model.get("rate_random_walk")
    return slow_noise(
        bi.sigma_dps if isinstance(bi, BiasInstability) else 0.0,
        bi.tau_s if isinstance(bi, BiasInstability) else 1.0,
        rw.k_dps_per_sqrt_s if isinstance(rw, RateRandomWalk) else 0.0,
        1.0 / data.fs_hz,
    )


def _from_differences(
    data: GapData, de: FloatArray, q_step: float, model: GyroModel, rows: BoolArray, after: float
) -> float:
    """W from neighbouring differences ``de`` of the residual: robust (1.4826 MAD)**2 / 2
    less q**2/12; on a lattice coarse against them their variance, or, where most of them are
    zero (the output mostly sits on its code) and the model quantizes, how often the output
    leaves its code at the samples ``rows`` (their true rate known at the sample). With a
    low-pass the level is carried to its input."""
    mad = float(np.median(np.abs(de - np.median(de))))
    lat = data.lattice
    bw = model.get("bandwidth")
    a = pole(bw.section_hz(), 1.0 / data.fs_hz) if isinstance(bw, Bandwidth) else 0.0
    order = bw.sections if isinstance(bw, Bandwidth) else 1
    if mad == 0.0 or (lat is not None and mad < 1.5 * lat.step_dps):
        sd = None
        if mad == 0.0 and q_step:  # most neighbours on one code: it mostly sits on its code
            sd = dither_sd(data.omega[rows], signal(data, model)[rows], q_step)
        if sd is not None:  # the variance at the ADC, carried back through the low-pass
            return max(sd * sd - after, _TINY) / noise_share(a, order)
        v = float(np.var(de)) / 2.0
    else:
        v = (1.4826 * mad) ** 2 / 2.0
    v = max(v - q_step**2 / 12.0, _TINY)
    return float(v * white_factor(a, order)) if a > 0 else float(v)


def _heading(data: GapData, d: FloatArray, q_step: float, model: GyroModel, after: float) -> float:
    """W with a heading truth. Where the log has a speed and stops, from neighbouring
    differences of omega - D inside the stops (:func:`stop_interior`: the true rate is zero
    there at every sample); else from second differences of omega - D on straight stretches
    (robust: MAD; a second difference of white noise has variance 6 sigma**2, and a yaw rate
    changing steadily has none). Between a GPS course's fixes the true rate is unknown:
    sampled at 1 Hz, a car's swaying and steering corrections change it from one sample to
    the next on a straight road as much as a phone gyro's noise, so the straights read the
    road as noise (a simulated 1 Hz phone drive: 10x its white noise)."""
    y = data.omega - d
    stop = stop_interior(data)
    pairs = stop[1:] & stop[:-1] & ~data.time_gap[1:]
    if int(pairs.sum()) >= MIN_STOP_PAIRS:
        return _from_differences(data, np.diff(y)[pairs], q_step, model, stop, after)
    ok = data.valid & (np.abs(data.truth_filled) < STRAIGHT_DPS)
    run = ok[2:] & ok[1:-1] & ok[:-2] & ~data.time_gap[2:] & ~data.time_gap[1:-1]
    if int(run.sum()) < 30:  # hardly any straight driving: all samples
        run = data.valid[2:] & data.valid[1:-1] & data.valid[:-2]
    d2 = np.diff(y, 2)[run]
    if d2.shape[0] < 10:
        return float(np.var(y[data.valid]))
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    v = (1.4826 * mad) ** 2 / 6.0 if mad > 0 else float(np.var(d2)) / 6.0
    v = max(v - q_step**2 / 12.0, _TINY)
    bw = model.get("bandwidth")
    if isinstance(bw, Bandwidth):
        v *= white_factor(pole(bw.section_hz(), 1.0 / data.fs_hz), bw.sections)
    return float(v)
