"""A gyro's error model as HDR+ uses it: Allan parameters, temperature coefficient, output step.

Pure data and arithmetic, no I/O. One vocabulary for the three places it comes from: a grade
preset (:func:`grade_noise`), the config's ``gyro.*`` keys, and the noise
parameters ``hdrd calibrate`` records beside the bias (:meth:`GyroNoise.to_dict` /
:meth:`GyroNoise.from_mapping`). :meth:`hdrd.core.plusparams.PlusParams.fitted` turns it into the
bias model's process noise (docs/hdrplus.md).

Units: rates deg/s, + = counter-clockwise seen from above; white noise deg/s/sqrt(Hz); rate
random walk deg/s/sqrt(s); temperature coefficient deg/s/degC; times s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

from hdrd.core.allan import allan_deviation, arw_from_adev, default_taus, gauss_markov_adev
from hdrd.core.grades import GM_PEAK, Grade
from hdrd.core.standstill import quantization_step

__all__ = [
    "ALLAN_MIN_S",
    "NOISE_KEYS",
    "WARMUP_DEG_C",
    "WARMUP_S",
    "GyroNoise",
    "grade_noise",
    "measure_noise",
    "noise_in_force",
]

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
    coefficient. quant_step_dps: the output step q, deg/s. motion_offset_dps and
    motion_offset_sd_dps: the unit's driving bias minus its bias at rest, deg/s, and how well
    it is known. stop_scatter_dps: how far one stop reads from another, deg/s (1 sigma).
    source: where it came from, for the reader and the published message (``grade crs03``,
    ``recorded``, ``config``, ``learned``).
    """

    white_dps_per_rthz: float = math.nan
    bias_instability_dps: float = math.nan
    bias_tau_s: float = 100.0
    rrw_dps_per_sqrt_s: float = math.nan
    temp_coeff_dps_per_c: float = math.nan
    quant_step_dps: float = math.nan
    motion_offset_dps: float = math.nan
    motion_offset_sd_dps: float = math.nan
    stop_scatter_dps: float = math.nan
    source: str = "given"

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "source":
                continue
            v = float(getattr(self, f.name))
            if f.name in SIGNED_KEYS:
                if not (math.isnan(v) or math.isfinite(v)):
                    raise ValueError(f"{f.name} must be a finite number (or unknown), got {v!r}")
            elif not (math.isnan(v) or (math.isfinite(v) and v >= 0.0)):
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

    def tracked_q_no_temp(self) -> float:
        """The part of :meth:`bias_q_no_temp` a bias estimate can follow, (deg/s)^2/s: the
        Gauss-Markov term only when its correlation time exceeds :data:`FAST_TAU_S` (a faster
        wander is heading noise, :meth:`fast_wander_q`); NaN when nothing is known."""
        fast = math.isfinite(self.bias_instability_dps) and self.bias_tau_s <= FAST_TAU_S
        q = self.bias_q_no_temp()
        if fast and math.isfinite(q):
            sigma = self.bias_instability_dps / GM_PEAK
            q -= 2.0 * sigma * sigma / self.bias_tau_s
        return q

    def fast_wander_q(self) -> float:
        """A Gauss-Markov bias whose correlation time is at most :data:`FAST_TAU_S` wanders
        too fast to follow from stops or roads: its integral is the heading's random walk,
        2 sigma^2 tau, deg^2/s (0 for a slower one; NaN unknown)."""
        if not math.isfinite(self.bias_instability_dps):
            return math.nan
        if self.bias_tau_s > FAST_TAU_S:
            return 0.0
        sigma = self.bias_instability_dps / GM_PEAK
        return 2.0 * sigma * sigma * self.bias_tau_s

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
            if key in SIGNED_KEYS:
                if not math.isfinite(v):
                    raise ValueError(f"{key} = {value!r} must be a finite number")
            elif not (math.isfinite(v) and v >= 0.0) or (key == "bias_tau_s" and not v > 0.0):
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
    "motion_offset_dps",
    "motion_offset_sd_dps",
    "stop_scatter_dps",
)
"""The parameters of :class:`GyroNoise` by name (bias files, the config's ``gyro.*``)."""

SIGNED_KEYS = frozenset({"motion_offset_dps"})
"""The parameters that may be negative."""

FAST_TAU_S = 120.0
"""A Gauss-Markov bias of at most this correlation time, s, is heading noise to HDR+, not a
bias to follow (:meth:`GyroNoise.fast_wander_q`)."""

ALLAN_MIN_S = 600.0
"""A standstill at least this long, s, is read for its bias instability and rate random walk
(an Allan deviation needs clusters many times the bias's correlation time)."""


def measure_noise(omega_dps: npt.ArrayLike, rate_hz: float, source: str = "recorded") -> GyroNoise:
    """The error model a standstill shows (raw rates in deg/s at ``rate_hz``), for ``hdrd
    calibrate`` to record beside the bias.

    Always: the white noise N (deg/s/sqrt(Hz): the Allan deviation's -1/2 line at 1 s when
    the window shows it, else the sample spread / sqrt(rate)) and the output step (the
    lattice of the values; unknown when not seen). From :data:`ALLAN_MIN_S` on, also the
    Allan floor as the bias instability (and its correlation time: the floor's cluster time
    / 1.89), when the curve turns before its end, and the rate random walk where its +1/2
    slope shows: the random walk HDR+'s bias model needs (:meth:`GyroNoise.bias_q`). The
    temperature coefficient is not seen at one temperature: unknown. ValueError for fewer
    than 2 finite samples or a rate that is not > 0.
    """
    w = np.asarray(omega_dps, dtype=np.float64)
    w = w[np.isfinite(w)]
    if w.shape[0] < 2 or not (math.isfinite(rate_hz) and rate_hz > 0.0):
        raise ValueError("measure_noise needs 2 or more finite samples and a rate > 0 Hz")
    white = float(np.std(w, ddof=1)) / math.sqrt(rate_hz)
    q = quantization_step(w)
    b_inst, b_tau, rrw = math.nan, 100.0, math.nan
    duration = w.shape[0] / rate_hz
    if default_taus(w.shape[0], rate_hz).shape[0] >= 3:
        taus, adev = allan_deviation(w, rate_hz)
        n_at_1 = arw_from_adev(taus, adev)
        if math.isfinite(n_at_1) and n_at_1 > 0.0:
            white = n_at_1
        if duration >= ALLAN_MIN_S:
            fit = _fit_adev(taus, adev)
            if fit is not None:
                sigma, b_tau, k = fit
                b_inst = GM_PEAK * sigma if sigma > 0.0 else math.nan
                rrw = k if k > 0.0 else math.nan
    return GyroNoise(
        white_dps_per_rthz=white,
        bias_instability_dps=b_inst,
        bias_tau_s=b_tau,
        rrw_dps_per_sqrt_s=rrw,
        quant_step_dps=q if q > 0.0 else math.nan,
        source=source,
    )


def _fit_adev(
    taus: npt.NDArray[np.float64], adev: npt.NDArray[np.float64]
) -> tuple[float, float, float] | None:
    """(sigma deg/s, tau_c s, K deg/s/sqrt(s)) of the model AVAR = N^2 / tau + GM(sigma,
    tau_c) + K^2 tau / 3 fitted to an Allan curve: for each tau_c on a grid (10 s .. a third
    of the longest cluster time), non-negative least squares of (N^2, sigma^2, K^2) in
    relative terms; the tau_c with the smallest residual. None when the curve has fewer than
    6 points or neither a Gauss-Markov nor a random-walk term is found."""
    from itertools import combinations

    if taus.shape[0] < 6:
        return None
    avar = adev * adev
    scale = 1.0 / avar  # relative residuals: every decade of tau counts alike
    best: tuple[float, float, float, float] | None = None
    for tau_c in np.geomspace(10.0, max(taus[-1] / 3.0, 10.0), 40):
        cols = np.stack(
            [1.0 / taus, gauss_markov_adev(taus, 1.0, float(tau_c)) ** 2, taus / 3.0], axis=1
        )
        a = cols * scale[:, None]
        y = avar * scale
        for keep in (c for r in (3, 2, 1) for c in combinations(range(3), r)):
            coef = np.zeros(3)
            sol, *_ = np.linalg.lstsq(a[:, keep], y, rcond=None)
            if np.any(sol < 0.0):
                continue
            coef[list(keep)] = sol
            res = float(np.sum((a @ coef - y) ** 2))
            if best is None or res < best[0] - 1e-12:
                best = (res, math.sqrt(coef[1]), float(tau_c), math.sqrt(coef[2]))
            break  # the largest non-negative subset at this tau_c
    if best is None or (best[1] <= 0.0 and best[3] <= 0.0):
        return None
    return best[1], best[2], best[3]


def noise_in_force(
    grade: str = "none",
    given: Mapping[str, float] | None = None,
    recorded: GyroNoise | None = None,
    learned: GyroNoise | None = None,
) -> GyroNoise | None:
    """The error model HDR+ is fitted to, from what is known, most specific first:

    1. ``recorded``: parameters ``hdrd calibrate`` measured on this gyro (the bias file), when
       they say how the bias moves (:meth:`GyroNoise.known`: a long enough standstill);
    2. ``given``: measured parameters from the configuration (``gyro.*``; 0 = not given;
       ``bias_tau_s`` only with a given bias instability; ``motion_offset_dps`` only with a
       ``motion_offset_sd_dps`` > 0), on top of the grade's when one is configured (source
       ``config``);
    3. the grade preset ``grade`` (source ``grade NAME``); ``none``: no grade.

    The unit's motion offset is the one known best: ``learned`` (what the daemon's trips
    taught, :mod:`hdrd.io.files.unitstate`) when its sd is below the configuration's (source
    ``learned``). None when nothing is known: HDR+ starts from the bank of a fresh unit.
    ValueError for an unknown grade."""
    merged, source = _configured(grade, dict(given or {}))
    if recorded is not None and recorded.known():
        merged = {**recorded.to_dict(), **{k: v for k, v in merged.items() if k in _UNIT_KEYS}}
        source = recorded.source
    if learned is not None and learned.motion_offset_sd_dps < merged.get(
        "motion_offset_sd_dps", math.inf
    ):
        merged["motion_offset_dps"] = learned.motion_offset_dps
        merged["motion_offset_sd_dps"] = learned.motion_offset_sd_dps
        source = learned.source
    if not merged:
        return None
    return GyroNoise.from_mapping(merged, source=source)


def _configured(grade: str, given: dict[str, float]) -> tuple[dict[str, float], str]:
    """The configuration's part of :func:`noise_in_force`: the grade's parameters with the
    ``gyro.*`` ones given on top (each only as the docstring there says), and their source."""
    base: dict[str, float] = {}
    source = "config"
    if grade != "none":
        g = grade_noise(grade)
        base = g.to_dict()
        source = g.source
    tau = given.pop("bias_tau_s", None)
    offset = given.pop("motion_offset_dps", None)
    extra = {k: float(v) for k, v in given.items() if v}
    if tau is not None and "bias_instability_dps" in extra:  # the given B's own time
        extra["bias_tau_s"] = float(tau)
    if offset is not None and "motion_offset_sd_dps" in extra:  # with its sd only
        extra["motion_offset_dps"] = float(offset)
    return {**base, **extra}, "config" if extra else source


_UNIT_KEYS = frozenset({"motion_offset_dps", "motion_offset_sd_dps", "stop_scatter_dps"})
"""What a standstill recording cannot show and the configuration or the road can: kept beside
a recorded error model."""


def grade_noise(name: str) -> GyroNoise:
    """The grade's error model as HDR+ uses it (:meth:`hdrd.core.plusparams.PlusParams.fitted`)."""
    g = Grade.from_table(name)
    return GyroNoise(
        white_dps_per_rthz=g.white_dps_per_rthz,
        bias_instability_dps=g.bias_instability_dps,
        bias_tau_s=g.bias_tau_s,
        rrw_dps_per_sqrt_s=g.rrw_dps_per_sqrt_s,
        temp_coeff_dps_per_c=g.temp_coeff_dps_per_c,
        quant_step_dps=g.quant_step_dps,
        source=f"grade {name}",
    )
