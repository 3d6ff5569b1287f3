"""The bounds the model-gap fits keep each bounded parameter in, and which fitted parameters
ended on one (reported: a value at a bound is a limit, not an estimate). Pure."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hdrd.analysis.gap.data import GapData
from hdrd.analysis.gap.lowpass import A_MAX, A_MIN, cutoff_hz
from hdrd.sim.effects import Bandwidth
from hdrd.sim.gyro import GyroModel

__all__ = [
    "DELAY_MAX_S",
    "GAIN_MIN",
    "WARMUP_TAU_MAX_S",
    "at_rest",
    "param_bounds",
    "params_at_bounds",
]

DELAY_MAX_S = 3.0
WARMUP_TAU_MAX_S = 1800.0
"""A gyro's own warm-up after power-on settles within minutes; an exponential of hours is the
surroundings warming (temperature_bias) or a random walk, and would trade places with them."""
GAIN_MIN = -0.9


def at_rest(data: GapData) -> bool:
    """The true rate is (near) zero throughout (99th percentile of |truth| below 1 deg/s) and
    known at every sample (not a GPS heading's: its fixes step): the unexplained residual's
    sample-to-sample structure is the sensor's own noise."""
    truth = data.truth[data.valid]
    if data.truth_source.startswith("heading_truth"):
        return False
    return truth.shape[0] == 0 or float(np.percentile(np.abs(truth), 99)) < 1.0


def param_bounds(data: GapData) -> dict[tuple[str, str], tuple[float, float, str]]:
    """The bounds the fits keep each bounded parameter in, (low, high, why), in the
    parameter's unit: what the log can resolve, or what the effect means."""
    b, d = data.block_s, data.duration_s
    dt = 1.0 / data.fs_hz
    return {
        ("warmup_transient", "tau_s"): (
            b,
            max(min(d / 2.0, WARMUP_TAU_MAX_S), 2.0 * b),
            f"one block .. half the log, at most {WARMUP_TAU_MAX_S:g} s (a slower transient is "
            "the surroundings' temperature or a random walk)",
        ),
        ("time_offset", "delay_s"): (-DELAY_MAX_S, DELAY_MAX_S, "lags of at most 3 s"),
        ("scale_factor", "error"): (GAIN_MIN, math.inf, "a gain above 0.1"),
        ("scale_asymmetry", "pos_error"): (GAIN_MIN, math.inf, "a gain above 0.1"),
        ("scale_asymmetry", "neg_error"): (GAIN_MIN, math.inf, "a gain above 0.1"),
        ("bias_instability", "tau_s"): (
            2.0 * b,
            10.0 * d,
            "two blocks .. ten times the log (faster is not resolved by the blocks)",
        ),
        ("bandwidth", "cutoff_hz"): (
            cutoff_hz(A_MAX, dt),
            cutoff_hz(A_MIN, dt),
            "a time constant of 1000 samples .. 1.1 x the sample rate (each section's)",
        ),
    }


def params_at_bounds(model: GyroModel, data: GapData) -> list[dict[str, Any]]:
    """The model's parameters that sit at (within 0.5 % of) a fit bound: the data pushed them
    there, so the value is a limit, not an estimate."""
    out: list[dict[str, Any]] = []
    for (eff, p), (lo, hi, why) in param_bounds(data).items():
        e = model.get(eff)
        if e is None:
            continue
        v = float(getattr(e, p))
        # A low-pass of several sections is bounded by its sections' pole.
        at = e.section_hz() if isinstance(e, Bandwidth) else v
        for side, lim in (("lower", lo), ("upper", hi)):
            if math.isfinite(lim) and abs(at - lim) <= 0.005 * max(abs(lim), 1e-12):
                out.append(
                    {
                        "effect": eff,
                        "param": p,
                        "value": float(f"{v:.6g}"),
                        "bound": side,
                        "limit": float(f"{lim:.6g}"),
                        "range": why,
                    }
                )
    return out
