"""The model's deterministic prediction D of a prepared log: its bias, gain, lag, low-pass and
clipping effects applied to the true rate with every random effect off, and where the true
rate is known at every sample the quantized output's mean over the fast noise that dithers
the ADC (:mod:`.dither`). Pure.

Rates deg/s, + = CCW; times s; temperatures deg C.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.data import GapData
from hdrd.analysis.gap.dither import DITHERED, expected_output, fast_noise_sd
from hdrd.sim.effects import Bandwidth, Quantization
from hdrd.sim.gyro import GyroModel

__all__ = ["NOISE_EFFECTS", "deterministic_part", "signal"]

FloatArray = npt.NDArray[np.float64]

NOISE_EFFECTS = ("bias_instability", "rate_random_walk", "white_noise", "quantization")
"""Effects with a random (or, for quantization, sub-sample) output: they shape the residual's
covariance and histogram; quantization enters D only as the mean of its output where the
true rate is known at every sample."""

_RNG0 = np.random.default_rng(0)


def signal(data: GapData, model: GyroModel) -> FloatArray:
    """What reaches the ADC without noise (deg/s per sample): the true rate through the
    model's deterministic effects (bias, gain, lag, low-pass, clipping), every random effect
    (the low-pass's output noise too) and the quantization off."""
    det = GyroModel(
        tuple(
            replace(e, output_noise_dps_per_rthz=0.0) if isinstance(e, Bandwidth) else e
            for e in model.effects
            if e.name not in NOISE_EFFECTS
        )
    )
    if not det.effects:
        return data.truth_filled.copy()
    return np.asarray(det.apply(data.t, data.truth_filled, data.temp_c, _RNG0, data.speed))


def deterministic_part(data: GapData, model: GyroModel) -> FloatArray:
    """D: what the model adds to the true rate with every random effect off (deg/s per
    sample), minus the truth. With a quantization in the model, at the samples whose true
    rate is known at the sample (:attr:`GapData.sample_truth`) the ADC's output is taken at
    its mean over the fast noise at its input (:func:`.dither.expected_output`): a gyro at
    rest whose noise never crosses a code reads that code, not its bias. Elsewhere (between
    a heading truth's fixes, while driving) the motion dithers the ADC and its mean is its
    input's."""
    x = signal(data, model)
    q = model.get("quantization")
    if isinstance(q, Quantization):
        sd = fast_noise_sd(model, data.fs_hz)
        rows = data.sample_truth
        if sd < DITHERED * q.step_dps and rows.any():
            x[rows] = expected_output(x[rows], sd, q.step_dps)[0]
    return np.asarray(x - data.truth_filled)
