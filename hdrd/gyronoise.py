"""A gyro's error model as HDR+ uses it: Allan parameters, temperature coefficient, output step.

Pure data and arithmetic, no I/O. One vocabulary for the three places it comes from: a grade
preset (:func:`hdrd.sim.grades.grade_noise`), the config's ``plus.noise`` keys, and the noise
parameters ``hdrd calibrate`` records beside the bias (:meth:`GyroNoise.to_dict` /
:meth:`GyroNoise.from_mapping`). :meth:`hdrd.hdrplus.HdrPlusParams.fitted` turns it into the
bias model's process noise (docs/hdrplus.md).

Units: rates deg/s, + = counter-clockwise seen from above; white noise deg/s/sqrt(Hz); rate
random walk deg/s/sqrt(s); temperature coefficient deg/s/degC; times s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

__all__ = ["GM_PEAK", "NOISE_KEYS", "WARMUP_DEG_C", "WARMUP_S", "GyroNoise"]

GM_PEAK = 0.62
"""Peak of a Gauss-Markov bias's Allan deviation in units of its sigma."""
WARMUP_DEG_C = 16.0
"""A cabin warm-up the bias model must follow without a temperature, degC (5 -> 21 degC: the
paper's Sec. 5 winter drives; the simulator's profiles)..."""
WARMUP_S = 900.0
"""... over about this long, s."""


@dataclass(frozen=True, slots=True)
class GyroNoise:
    """A gyro's error model (IEEE Std 952 terms; NaN = unknown).

    white_dps_per_rthz: white rate noise N, deg/s/sqrt(Hz). bias_instability_dps: the Allan
    floor B, deg/s (a Gauss-Markov bias of sigma B / 0.62 and correlation time bias_tau_s, s).
    rrw_dps_per_sqrt_s: rate random walk K. temp_coeff_dps_per_c: the bias temperature
    coefficient. quant_step_dps: the output step q, deg/s. source: where it came from, for
    the reader and the published message (``grade crs03``, ``recorded``, ``config``).
    """

    white_dps_per_rthz: float = math.nan
    bias_instability_dps: float = math.nan
    bias_tau_s: float = 100.0
    rrw_dps_per_sqrt_s: float = math.nan
    temp_coeff_dps_per_c: float = math.nan
    quant_step_dps: float = math.nan
    source: str = "given"

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "source":
                continue
            v = float(getattr(self, f.name))
            if not (math.isnan(v) or (math.isfinite(v) and v >= 0.0)):
                raise ValueError(f"{f.name} must be a number >= 0 (or unknown), got {v!r}")
            if f.name == "bias_tau_s" and not v > 0.0:
                raise ValueError(f"bias_tau_s must be > 0, got {v!r}")
            object.__setattr__(self, f.name, v)

    def bias_q(self) -> float:
        """Random walk of the bias a temperature model cannot explain, (deg/s)^2/s:
        K^2 + 2 sigma^2 / tau (the Gauss-Markov term's rate of variance growth); NaN when
        neither term is known."""
        terms = []
        if math.isfinite(self.rrw_dps_per_sqrt_s):
            terms.append(self.rrw_dps_per_sqrt_s**2)
        if math.isfinite(self.bias_instability_dps):
            sigma = self.bias_instability_dps / GM_PEAK
            terms.append(2.0 * sigma * sigma / self.bias_tau_s)
        return float(sum(terms)) if terms else math.nan

    def bias_q_no_temp(self) -> float:
        """The same without a temperature: plus a warm-up of WARMUP_DEG_C over WARMUP_S seen
        as a random walk, (TC * dT)^2 / t."""
        q = self.bias_q()
        if not math.isfinite(self.temp_coeff_dps_per_c):
            return q
        warm = (self.temp_coeff_dps_per_c * WARMUP_DEG_C) ** 2 / WARMUP_S
        return (q if math.isfinite(q) else 0.0) + warm

    def known(self) -> bool:
        """True when it says how the bias moves (a random walk can be derived)."""
        return math.isfinite(self.bias_q_no_temp())

    def to_dict(self) -> dict[str, float]:
        """The known parameters by name (:data:`NOISE_KEYS`), as a bias file records them."""
        return {k: float(getattr(self, k)) for k in NOISE_KEYS if math.isfinite(getattr(self, k))}

    @classmethod
    def from_mapping(cls, data: Mapping[str, object], source: str = "given") -> GyroNoise:
        """From a mapping of :data:`NOISE_KEYS` (any subset); ValueError naming a key that is
        unknown or a value that is not a number >= 0."""
        kw: dict[str, float] = {}
        for key, value in data.items():
            if key not in NOISE_KEYS:
                raise ValueError(
                    f"unknown noise parameter {key!r} (allowed: {', '.join(NOISE_KEYS)})"
                )
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{key} = {value!r} is not a number")
            v = float(value)
            if not (math.isfinite(v) and v >= 0.0) or (key == "bias_tau_s" and not v > 0.0):
                raise ValueError(f"{key} = {value!r} must be a finite number >= 0")
            kw[key] = v
        return cls(**kw, source=source)


NOISE_KEYS: tuple[str, ...] = (
    "white_dps_per_rthz",
    "bias_instability_dps",
    "bias_tau_s",
    "rrw_dps_per_sqrt_s",
    "temp_coeff_dps_per_c",
    "quant_step_dps",
)
"""The parameters of :class:`GyroNoise` by name (bias files, the config's ``plus.noise``)."""
