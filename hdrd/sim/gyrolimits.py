"""What a gyro can have: a bound on every parameter of the error model (:mod:`hdrd.sim.gyro`)
that a model read from a file must keep (``simulate --model``, ``gap --model``, the fitted
errors of ``simulate --errors-from``). Pure data and one check.

The bounds are generous: each lies well beyond the worst gyro of any grade hdrd knows (the
largest built-in values are a phone's 2000 deg/s range, 0.12 deg/s/sqrt(Hz) of noise at a
1 Hz log, 1 deg/s of bias), and short of what makes no sense for a sensor on a vehicle: a
bias beyond 100 deg/s is no bias but a broken part, a scale factor error beyond 100 % no gain
error but another sensor, and values such as 1e308 overflow the simulation into a log of
infinite rates (which ``hdrd evaluate`` then refuses, its rates beyond ``--max-rate``).
The fits of ``hdrd gap`` are not held to them (a fit reports what the data say); a fitted
model beyond them is refused when it is read back. docs/gyro-model.md, "Limits", lists them.
"""

from __future__ import annotations

import math

__all__ = ["LIMITS", "limit_problem"]

LIMITS: dict[tuple[str, str], tuple[float, float, str]] = {
    ("time_offset", "delay_s"): (-60.0, 60.0, "s"),
    ("scale_factor", "error"): (-0.99, 1.0, "(a gain of 0.01 to 2)"),
    ("scale_asymmetry", "pos_error"): (-0.99, 1.0, "(a gain of 0.01 to 2)"),
    ("scale_asymmetry", "neg_error"): (-0.99, 1.0, "(a gain of 0.01 to 2)"),
    ("static_bias", "bias_dps"): (-100.0, 100.0, "deg/s"),
    ("warmup_transient", "amplitude_dps"): (-100.0, 100.0, "deg/s"),
    ("warmup_transient", "tau_s"): (1e-3, 86400.0, "s"),
    ("temperature_bias", "coeff_dps_per_c"): (-1.0, 1.0, "deg/s/degC"),
    ("temperature_bias", "ref_temp_c"): (-100.0, 200.0, "degC"),
    ("temperature_bias", "quad_dps_per_c2"): (-0.1, 0.1, "deg/s/degC^2"),
    ("motion_offset", "offset_dps"): (-100.0, 100.0, "deg/s"),
    ("motion_offset", "moving_mps"): (0.0, 100.0, "m/s"),
    ("motion_offset", "coeff_dps_per_mps"): (-1.0, 1.0, "deg/s per m/s"),
    ("stop_offset", "sd_dps"): (0.0, 100.0, "deg/s"),
    ("stop_offset", "moving_mps"): (0.0, 100.0, "m/s"),
    ("bias_instability", "sigma_dps"): (0.0, 100.0, "deg/s"),
    ("bias_instability", "tau_s"): (1e-3, 1e7, "s"),
    ("rate_random_walk", "k_dps_per_sqrt_s"): (0.0, 1.0, "deg/s/sqrt(s)"),
    ("white_noise", "density_dps_per_rthz"): (0.0, 1.0, "deg/s/sqrt(Hz)"),
    ("bandwidth", "cutoff_hz"): (1e-6, 1e5, "Hz"),
    ("bandwidth", "output_noise_dps_per_rthz"): (0.0, 1.0, "deg/s/sqrt(Hz)"),
    ("bandwidth", "sections"): (1.0, 4.0, "equal first-order sections"),
    ("saturation", "limit_dps"): (1.0, 10000.0, "deg/s"),
    ("quantization", "step_dps"): (1e-9, 10.0, "deg/s"),
}
"""(effect, parameter) -> (least, most, unit): the values a gyro can have, both ends allowed."""


def limit_problem(effect: str, param: str, value: float) -> str | None:
    """Why ``effect.param = value`` is no gyro's (one line naming the parameter, the value and
    what is allowed), or None. A parameter without a bound is not checked here."""
    bound = LIMITS.get((effect, param))
    if bound is None:
        return None
    lo, hi, unit = bound
    if math.isfinite(value) and lo <= value <= hi:
        return None
    return (
        f"{effect}.{param}: {value!r} is beyond what a gyro has (allowed: {lo:g} to {hi:g} {unit})"
    )
