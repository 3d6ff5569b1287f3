"""The simulator's gyro of a grade: :func:`grade_model` builds a
:class:`~hdrd.sim.gyro.GyroModel` from a row of the grade table (:mod:`hdrd.core.grades`, the
one place a grade's parameters live), and :func:`model_noise` reads a model back as HDR+'s
error model. The effects themselves live in :mod:`hdrd.sim.gyro`.

The CRS03-04 grade is the default model (:func:`hdrd.sim.gyro.crs03_default_model`) exactly,
so the paper-like benchmark is unchanged by it."""

from __future__ import annotations

import math

import numpy as np

from hdrd.core.grades import GM_PEAK, Grade
from hdrd.core.gyronoise import GyroNoise
from hdrd.sim.effects import (
    Bandwidth,
    BiasInstability,
    Effect,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleFactor,
    StaticBias,
    TemperatureBias,
    WhiteNoise,
)
from hdrd.sim.gyro import GyroModel, crs03_default_model

__all__ = ["grade_model", "model_noise"]


def grade_model(name: str, seed: int = 0) -> GyroModel:
    """The error model of grade ``name`` for one drive: its turn-on bias drawn from ``seed``
    (normal, mean startup_bias_dps, sd startup_bias_sd_dps; a stream of its own, so the route,
    temperature and noise of a seed are the same in every grade).

    ``crs03`` is :func:`hdrd.sim.gyro.crs03_default_model` exactly (its bias has no spread).
    """
    g = Grade.from_table(name)
    if name == "crs03":
        return crs03_default_model()
    bias = g.startup_bias_dps
    if g.startup_bias_sd_dps > 0.0:
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x6772616465])  # "grade"
        bias += g.startup_bias_sd_dps * float(rng.standard_normal())
    effects: list[Effect] = [
        ScaleFactor(error=g.scale_error),
        StaticBias(bias_dps=bias),
        TemperatureBias(coeff_dps_per_c=g.temp_coeff_dps_per_c, ref_temp_c=25.0),
        BiasInstability(sigma_dps=g.bias_instability_dps / GM_PEAK, tau_s=g.bias_tau_s),
        RateRandomWalk(k_dps_per_sqrt_s=g.rrw_dps_per_sqrt_s),
        WhiteNoise(density_dps_per_rthz=g.white_dps_per_rthz),
        Bandwidth(cutoff_hz=g.bandwidth_hz),
        Saturation(limit_dps=g.range_dps),
        Quantization(step_dps=g.quant_step_dps),
    ]
    return GyroModel(tuple(effects))


def model_noise(model: GyroModel, source: str = "model") -> GyroNoise:
    """A gyro error model's effects as HDR+'s error model (:class:`hdrd.core.gyronoise.GyroNoise`):
    white noise density, the Gauss-Markov bias as its Allan peak (0.62 sigma) and correlation
    time, the rate random walk, the linear temperature coefficient, the output step; a
    missing effect is unknown. For a model fitted to a drive (``hdrd gap``) to become the
    ``gyro.*`` keys or a bias file's ``noise``."""
    nan = math.nan
    white = model.get("white_noise")
    gm = model.get("bias_instability")
    rrw = model.get("rate_random_walk")
    temp = model.get("temperature_bias")
    quant = model.get("quantization")
    return GyroNoise(
        white_dps_per_rthz=getattr(white, "density_dps_per_rthz", nan),
        bias_instability_dps=GM_PEAK * gm.sigma_dps if isinstance(gm, BiasInstability) else nan,
        bias_tau_s=gm.tau_s if isinstance(gm, BiasInstability) else 100.0,
        rrw_dps_per_sqrt_s=getattr(rrw, "k_dps_per_sqrt_s", nan),
        temp_coeff_dps_per_c=abs(getattr(temp, "coeff_dps_per_c", nan)),
        quant_step_dps=getattr(quant, "step_dps", nan),
        source=source,
    )
